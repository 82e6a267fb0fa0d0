/*
 * script_upload.c: the import command: checking the model file, streaming
 * it to the server as OBJECT_UPLOAD_BEGIN, chunks and END under a window
 * of acknowledged bytes, and, for --anchor base and --drop, moving the new
 * object where its box must go with an OBJECT_PLACE once the server has
 * said where that box is.
 */
#include "scriptInt.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#include "log.h"
#include "utf8.h"

/* A model file larger than this is refused before a byte is sent. The
 * server's own cap is far lower (16 MiB by default, --max-upload) and is the
 * one that normally speaks, in an OBJECT_REJECTED; this one keeps a wrong
 * path (a disk image) from streaming for minutes first, and keeps the size
 * well inside the wire's u32. */
#ifndef IMPORT_FILE_MAX
#define IMPORT_FILE_MAX (1024ull * 1024u * 1024u)
#endif
_Static_assert(IMPORT_FILE_MAX <= UINT32_MAX, "total_size is a u32");
/* An import is given up when it has made no progress for this long: no
 * frame of it could be sent, or, once its end is out, no answer came.
 * Importing a large model (voxelizing, clustering) takes the server a while. */
#ifndef IMPORT_TIMEOUT_S
#define IMPORT_TIMEOUT_S 120
#endif
#define IMPORT_TIMEOUT_NS ((uint64_t)IMPORT_TIMEOUT_S * NS_PER_S)
#define IMPORT_CHECK_NS NS_PER_S
/* Upload frames sent per wakeup, so that reading (and the pongs and events
 * that brings) and timers run between slices of a large upload: 4 chunks
 * are 64 KiB. */
#define IMPORT_FRAMES_PER_WAKEUP 4
/* The upload's window. The socket buffers on both ends hold megabytes (all
 * of a model, on loopback), and whatever else we send (moves, pongs) waits
 * behind them until the server has read them. So every IMPORT_PROBE_BYTES
 * the upload sends a ping whose pong says the server has read that far, and
 * it stays at most IMPORT_WINDOW_BYTES ahead of the last one answered: at
 * 256 KiB a 50 ms round trip still allows 5 MB/s. */
#ifndef IMPORT_WINDOW_BYTES
#define IMPORT_WINDOW_BYTES (256u * 1024u)
#endif
#define IMPORT_PROBE_BYTES (IMPORT_WINDOW_BYTES / 4u)
_Static_assert(IMPORT_PROBE_BYTES >= PROTO_CHUNK_MAX, "at least a chunk between probes");
/* The probes' stamps: IMPORT_PROBE_MARK, the upload id in bits 32..62
 * (cut), the offset reached below. */
/* A model whose box is already this close to where its anchor or --drop
 * puts it is not placed a second time. */
#define SETTLE_EPS_M 1e-4
#define PI 3.14159265358979323846

/* The object's name from the file's base name, for an import without
 * --name: what the text rule forbids (control characters, broken UTF-8)
 * becomes '?', and it is cut at the last character boundary within
 * PROTO_OBJECT_NAME_MAX bytes. */
static void name_from_path(const char *path, char out[PROTO_OBJECT_NAME_MAX + 1])
{
    const char *slash = strrchr(path, '/');
    const uint8_t *base = (const uint8_t *)(slash ? slash + 1 : path);
    size_t n = strlen((const char *)base), o = 0;
    for (size_t i = 0; i < n;) {
        uint32_t cp;
        size_t k = utf8_next(base + i, n - i, &cp);
        int bad = k == 0 || cp < 0x20u || cp == 0x7fu;
        size_t w = bad ? 1 : k;
        if (o + w > PROTO_OBJECT_NAME_MAX)
            break;
        if (bad)
            out[o] = '?';
        else
            memcpy(out + o, base + i, k);
        o += w;
        i += k ? k : 1;
    }
    if (o == 0)
        memcpy(out, "model", (o = 5));
    out[o] = '\0';
}

/* The format hint: the base name's extension lowercased when it is 1 to
 * PROTO_FORMAT_MAX letters and digits, else "" for the server to detect. */
static void format_from_path(const char *path, char out[PROTO_FORMAT_MAX + 1])
{
    const char *slash = strrchr(path, '/');
    const char *base = slash ? slash + 1 : path;
    const char *dot = strrchr(base, '.');
    out[0] = '\0';
    if (!dot || dot == base)
        return;
    size_t n = strlen(dot + 1);
    if (n == 0 || n > PROTO_FORMAT_MAX)
        return;
    for (size_t i = 0; i < n; i++) {
        char ch = dot[1 + i];
        if (ch >= 'A' && ch <= 'Z')
            ch = (char)(ch - 'A' + 'a');
        if (!((ch >= 'a' && ch <= 'z') || (ch >= '0' && ch <= '9'))) {
            out[0] = '\0';
            return;
        }
        out[i] = ch;
    }
    out[n] = '\0';
}

static uint64_t probe_stamp(const script *s, uint32_t off)
{
    return IMPORT_PROBE_MARK | (uint64_t)(s->imp_id & 0x7fffffffu) << 32 | off;
}

float script__yaw_radians(double deg) { return (float)(fmod(deg, 360.0) * (PI / 180.0)); }

/*
 * Ends an upload the file failed in the middle of. The server holds one
 * upload per connection until it is complete, so it is ended early: an
 * OBJECT_UPLOAD_END short of the announced size makes the server drop it
 * and say so, and the import is over ("failed") when that rejection comes.
 * Returns 0 while waiting for it, or the session's -errno if even that
 * could not be sent.
 */
static int import_abort(script *s)
{
    proto_upload_end e = {.upload_id = s->imp_id, .at = {.scale = 1.0f}};
    int rc = session_send_upload_end(s->c, &e);
    if (rc < 0)
        return rc;
    close(s->imp_fd);
    s->imp_fd = -1;
    s->imp_phase = IMPORT_WAIT;
    s->imp_aborted = 1;
    s->t_progress = ev_now(s->loop);
    return 0;
}

/*
 * Sends what is next of the running import, up to IMPORT_FRAMES_PER_WAKEUP
 * frames and only while the backlog is empty, then asks for an on_writable
 * call to go on; nothing once the END is out. Returns 0, or the session's
 * -errno when the file failed and not even the early END could be sent
 * (the caller ends the command). A session that cannot send any more is
 * left to on_close, which ends the run.
 */
int script__import_pump(script *s)
{
    for (int budget = IMPORT_FRAMES_PER_WAKEUP; s->imp_phase >= IMPORT_BEGIN && s->imp_phase <= IMPORT_END;
         budget--) {
        if (budget == 0 || session_out_pending(s->c) > 0) {
            session_want_writable(s->c);
            return 0;
        }
        int rc;
        if (s->imp_phase == IMPORT_BEGIN) {
            char name[PROTO_OBJECT_NAME_MAX + 1], format[PROTO_FORMAT_MAX + 1];
            if (s->cur.name[0])
                snprintf(name, sizeof name, "%s", s->cur.name);
            else
                name_from_path(s->cur.file, name);
            format_from_path(s->cur.file, format);
            proto_upload_begin b = {.upload_id = s->imp_id, .total_size = s->imp_size,
                                    .name = {name, (uint32_t)strlen(name)},
                                    .format = {format, (uint32_t)strlen(format)},
                                    .up_axis = (uint8_t)s->cur.up_axis, .unit_scale = (float)s->cur.unit_scale};
            rc = session_send_upload_begin(s->c, &b);
            if (rc == 0) {
                /* Chunks wait for this probe's pong: a refused BEGIN (too
                 * big, one upload at a time) is answered before it, and
                 * chunks sent meanwhile would each be refused too. */
                session_send_ping(s->c, probe_stamp(s, 0));
                s->imp_phase = IMPORT_CHUNKS;
            }
        } else if (s->imp_phase == IMPORT_CHUNKS) {
            if (!s->imp_begun || s->imp_off - s->imp_acked >= IMPORT_WINDOW_BYTES)
                return 0; /* the pong of a probe goes on */
            uint32_t want = s->imp_size - s->imp_off;
            if (want > PROTO_CHUNK_MAX)
                want = PROTO_CHUNK_MAX;
            ssize_t k = pread(s->imp_fd, s->chunk, want, (off_t)s->imp_off);
            if (k < 0 && errno == EINTR)
                continue;
            if (k <= 0) {
                script__obj_error(s, "import: cannot read %s: %s", s->cur.file,
                                  k < 0 ? strerror(errno) : "the file shrank while it was being sent");
                return import_abort(s);
            }
            rc = session_send_upload_chunk(s->c, s->imp_id, s->imp_off, s->chunk, (uint32_t)k);
            if (rc == 0) {
                s->imp_off += (uint32_t)k;
                if (s->imp_off == s->imp_size)
                    s->imp_phase = IMPORT_END;
                else if (s->imp_off >= s->imp_probe_at) {
                    /* Fits: the backlog holds at most this chunk's rest. */
                    session_send_ping(s->c, probe_stamp(s, s->imp_off));
                    s->imp_probe_at = s->imp_off + IMPORT_PROBE_BYTES;
                }
            }
        } else {
            proto_upload_end e = {.upload_id = s->imp_id,
                                  .at = {.pos = {(float)s->cur.arg[0], (float)s->cur.arg[1], (float)s->cur.arg[2]},
                                         .yaw = script__yaw_radians(s->cur.yaw_deg), .scale = (float)s->cur.size}};
            rc = session_send_upload_end(s->c, &e);
            if (rc == 0) {
                s->imp_phase = IMPORT_WAIT;
                close(s->imp_fd);
                s->imp_fd = -1;
            }
        }
        if (rc == -ENOBUFS) {
            session_want_writable(s->c);
            return 0;
        }
        if (rc < 0)
            return 0; /* the session is ending; on_close follows */
        s->t_progress = ev_now(s->loop);
    }
    return 0;
}

void script__import_probed(script *s, uint64_t stamp)
{
    uint32_t off = (uint32_t)stamp;
    if (!s->running || s->cur.op != SCRIPT_IMPORT || s->imp_phase != IMPORT_CHUNKS ||
        stamp != probe_stamp(s, off) || off > s->imp_off || (s->imp_begun && off <= s->imp_acked))
        return;
    s->imp_begun = 1;
    s->imp_acked = off;
    s->t_progress = ev_now(s->loop);
    if (session_out_pending(s->c) == 0 && script__import_pump(s) < 0)
        script__obj_finish(s, "failed", NULL);
}

void script__import_start(script *s)
{
    const char *file = s->cur.file;
    struct stat st;
    s->imp_fd = open(file, O_RDONLY | O_CLOEXEC | O_NONBLOCK); /* a FIFO must not block us */
    if (s->imp_fd < 0 || fstat(s->imp_fd, &st) < 0) {
        script__obj_error(s, "import: cannot read %s: %s", file, strerror(errno));
    } else if (!S_ISREG(st.st_mode)) {
        script__obj_error(s, "import: cannot read %s: not a regular file", file);
    } else if (st.st_size == 0) {
        script__obj_error(s, "import: cannot read %s: the file is empty", file);
    } else if ((unsigned long long)st.st_size > IMPORT_FILE_MAX) {
        script__obj_error(s, "import: cannot read %s: %lld bytes, over the limit of %llu bytes", file,
                          (long long)st.st_size, (unsigned long long)IMPORT_FILE_MAX);
    } else {
        if (++s->last_upload_id == 0)
            s->last_upload_id = 1;
        s->imp_id = s->last_upload_id;
        s->imp_size = (uint32_t)st.st_size;
        s->imp_off = s->imp_acked = 0;
        s->imp_begun = 0;
        s->imp_object = 0;
        s->imp_probe_at = IMPORT_PROBE_BYTES;
        s->imp_phase = IMPORT_BEGIN;
        s->t_progress = ev_now(s->loop);
        s->cmd_timer = session_timer_start(s->loop, IMPORT_CHECK_NS, IMPORT_CHECK_NS, script__on_cmd_timer, s);
        if (script__import_pump(s) == 0)
            return;
    }
    script__obj_done(s, "failed", NULL);
}

void script__import_check(script *s, uint64_t now)
{
    if (s->imp_phase == IMPORT_SETTLE) {
        if (now - s->t_progress >= OBJECT_WAIT_NS) {
            log_warn("import: object %" PRIu32 " made, but no answer to placing it within %llu s", s->imp_object,
                     OBJECT_WAIT_NS / NS_PER_S);
            script__obj_finish(s, "timeout", NULL);
        }
        return;
    }
    if (now - s->t_progress >= IMPORT_TIMEOUT_NS) {
        log_warn("import of %s: %s for %llu s; giving up", s->cur.file,
                 s->imp_phase == IMPORT_WAIT ? "no answer from the server" : "could not send",
                 (unsigned long long)(IMPORT_TIMEOUT_NS / NS_PER_S));
        script__obj_finish(s, s->imp_aborted ? "failed" : "timeout", NULL);
    }
}

/*
 * Where the import's new object o must stand for its anchor and --drop,
 * from the box around its boxes as the server placed them (world
 * coordinates, so a translation of the object moves them by as much).
 * Returns 1 with pos set when it must be moved, 0 when it stays where it
 * is: anchored by its origin and not dropped, already there, or without
 * boxes to go by.
 */
static int settle_target(const script *s, const proto_object_info *o, float pos[3])
{
    float lo[3], hi[3];
    double off[3] = {0.0, 0.0, 0.0};
    if (s->cur.anchor == SCRIPT_ANCHOR_ORIGIN && !s->cur.drop)
        return 0;
    if (known_bounds(o, lo, hi) < 0) {
        log_warn("import: object %" PRIu32 " has no collision boxes: left at its origin", o->object_id);
        return 0;
    }
    if (s->cur.anchor == SCRIPT_ANCHOR_BASE) {
        off[0] = s->cur.arg[0] - ((double)lo[0] + hi[0]) / 2.0;
        off[1] = s->cur.arg[1] - lo[1];
        off[2] = s->cur.arg[2] - ((double)lo[2] + hi[2]) / 2.0;
    }
    if (s->cur.drop) {
        float flo[3], fhi[3];
        for (int a = 0; a < 3; a++) {
            flo[a] = (float)(lo[a] + off[a]);
            fhi[a] = (float)(hi[a] + off[a]);
        }
        float floor_y = session_get_view(s->c)->welcome.world_min[1];
        off[1] += (double)known_surface_below(s->objs, o->object_id, flo, fhi, floor_y) - flo[1];
    }
    if (fabs(off[0]) < SETTLE_EPS_M && fabs(off[1]) < SETTLE_EPS_M && fabs(off[2]) < SETTLE_EPS_M)
        return 0;
    for (int a = 0; a < 3; a++)
        pos[a] = (float)(o->at.pos[a] + off[a]);
    return 1;
}

void script__import_object(script *s, const proto_object_info *o)
{
    if (s->imp_phase == IMPORT_SETTLE) {
        if (o->object_id == s->imp_object)
            script__obj_finish(s, "ok", o);
        return;
    }
    if (s->imp_phase == IMPORT_NONE || o->upload_id != s->imp_id)
        return;
    s->imp_object = o->object_id;
    proto_object_place p = {.object_id = o->object_id, .at = {.yaw = o->at.yaw, .scale = o->at.scale}};
    if (!settle_target(s, o, p.at.pos)) {
        script__obj_finish(s, "ok", o);
        return;
    }
    int rc = session_send_object_place(s->c, &p);
    if (rc < 0) {
        script__obj_error(s, "import: object %" PRIu32 " made, but not moved to its place: %s", o->object_id,
                          strerror(-rc));
        script__obj_finish(s, "failed", o);
        return;
    }
    s->imp_phase = IMPORT_SETTLE;
    s->t_progress = ev_now(s->loop);
}
