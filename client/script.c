/* script.c: the scripted and interactive client (see script.h). */
#include "script.h"

#include <errno.h>
#include <fcntl.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <sys/types.h>
#include <unistd.h>

#include "alloc.h"
#include "events.h"
#include "log.h"
#include "utf8.h"

#define NS_PER_MS 1000000ull
#define NS_PER_S 1000000000ull

/* A move is done when the server has put us this close to the target, */
#define MOVE_REACHED_M 0.01
/* or when the authoritative position has not come MOVE_PROGRESS_M closer for
 * MOVE_STALL_NS (something blocks the way), or after MOVE_TIMEOUT_NS. */
#define MOVE_PROGRESS_M 0.001
#define MOVE_STALL_NS (1ull * NS_PER_S)
#define MOVE_TIMEOUT_NS (60ull * NS_PER_S)
/* A walk whose last move is never acknowledged (it changed nothing, so no
 * snapshot says so) is done this long after that move. */
#define WALK_ACK_WAIT_NS (2ull * NS_PER_S)
/* How long a ping command waits for its pong before moving on. */
#define PING_WAIT_NS (5ull * NS_PER_S)
/* After bye, how long the server gets to close before we do. */
#define QUIT_LINGER_NS (1ull * NS_PER_S)
/* How often the keepalive is considered: well under any sane idle timeout. */
#define KEEPALIVE_CHECK_NS (NS_PER_S / 4)

/* Argument bounds: a day of waiting or walking keeps every derived time far
 * inside a u64 of nanoseconds; coordinates must survive conversion to the
 * wire's f32 and stay meaningful in metres. */
#define WAIT_MAX_MS 86400000.0
#define WALK_MAX_S 86400.0
#define COORD_MAX 1e7

/* Objects. Scales are checked as typed, against the decimal bounds: the f32
 * they round to are exactly PROTO_SCALE_MIN and PROTO_SCALE_MAX, so what
 * passes here passes the server's check. A yaw is reduced modulo 360 before
 * it is turned into radians, so the bound only keeps typos out. */
#define OBJ_SCALE_MIN 0.001
#define OBJ_SCALE_MAX 1000.0
#define YAW_MAX_DEG 1e6
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
/* The probes' stamps: this bit, the upload id in bits 32..62 (cut), the
 * offset reached below. The ping command's and the keepalive's stamps are
 * clock readings in microseconds, which never reach bit 63. */
#define IMPORT_PROBE_MARK (1ull << 63)
/* How long place and remove wait for the server's answer. */
#define OBJECT_WAIT_NS (5ull * NS_PER_S)
#define PI 3.14159265358979323846

/* ---- parsing ----------------------------------------------------------- */

/* Words on one line: a full import has 16. */
#define WORDS_MAX 24

static const struct {
    const char *name;
    int op;
    int nargs; /* -1: parsed by a function of its own */
    const char *usage;
} commands[] = {
    {"move", SCRIPT_MOVE, 3, "move X Y Z"},
    {"walk", SCRIPT_WALK, 3, "walk DX DZ SECONDS"},
    {"wait", SCRIPT_WAIT, 1, "wait MS"},
    {"ping", SCRIPT_PING, 0, "ping"},
    {"import", SCRIPT_IMPORT, -1,
     "import FILE [--up y|z] [--scale UNITS] [--name NAME] at X Y Z [--yaw DEGREES] [--size S]"},
    {"place", SCRIPT_PLACE, -1, "place ID X Y Z [--yaw DEGREES] [--size S]"},
    {"remove", SCRIPT_REMOVE, -1, "remove ID"},
    {"quit", SCRIPT_QUIT, 0, "quit"},
};
#define NCOMMANDS (sizeof commands / sizeof commands[0])

/* Parses a whole token as a number within [lo, hi]; strtod alone would take
 * "nan", "inf" and trailing junk. Returns 0 or -1. */
static int parse_number(const char *tok, double lo, double hi, double *out)
{
    char *end;
    double v = strtod(tok, &end);
    if (end == tok || *end != '\0' || !isfinite(v) || v < lo || v > hi)
        return -1;
    *out = v;
    return 0;
}

/* An object id: decimal digits only, 1..2^32-1 (0 means "none" on the wire). */
static int parse_id(const char *tok, uint32_t *out)
{
    if (*tok < '0' || *tok > '9')
        return -1;
    char *end;
    errno = 0;
    unsigned long long v = strtoull(tok, &end, 10);
    if (*end != '\0' || errno || v == 0 || v > UINT32_MAX)
        return -1;
    *out = (uint32_t)v;
    return 0;
}

static int is_blank(char ch) { return ch == ' ' || ch == '\t' || ch == '\r' || ch == '\v' || ch == '\f'; }

/*
 * Splits buf in place into words (at most WORDS_MAX) at blanks. A word that
 * starts with a double quote runs to the next one and may hold blanks and
 * '#' (there is no escape: a path with a quote in it cannot be written); an
 * unquoted '#' ends the line. Returns the count, or -1 with a message.
 */
static int split_words(char *buf, char **word, char *err, size_t errlen)
{
    int n = 0;
    char *p = buf;
    for (;;) {
        while (is_blank(*p))
            p++;
        if (*p == '\0' || *p == '#')
            return n;
        if (n == WORDS_MAX) {
            snprintf(err, errlen, "too many words");
            return -1;
        }
        if (*p == '"') {
            char *close = strchr(p + 1, '"');
            if (!close) {
                snprintf(err, errlen, "unterminated quote");
                return -1;
            }
            *close = '\0';
            word[n++] = p + 1;
            p = close + 1;
            if (*p != '\0' && *p != '#' && !is_blank(*p)) {
                snprintf(err, errlen, "a blank must follow a closing quote");
                return -1;
            }
            continue;
        }
        word[n++] = p;
        while (*p != '\0' && *p != '#' && !is_blank(*p))
            p++;
        if (*p == '#') {
            *p = '\0';
            return n;
        }
        if (*p != '\0')
            *p++ = '\0';
    }
}

/* An object name as the wire takes it: 1..PROTO_OBJECT_NAME_MAX bytes of
 * well-formed UTF-8 without control characters (PROTOCOL.md's text rule). */
static int object_name_ok(const char *name)
{
    size_t n = strlen(name);
    if (n == 0 || n > PROTO_OBJECT_NAME_MAX)
        return 0;
    for (size_t i = 0; i < n;) {
        uint32_t cp;
        size_t k = utf8_next((const uint8_t *)name + i, n - i, &cp);
        if (k == 0 || cp < 0x20u || cp == 0x7fu)
            return 0;
        i += k;
    }
    return 1;
}

enum { OPT_AT, OPT_UP, OPT_SCALE, OPT_NAME, OPT_YAW, OPT_SIZE, OPT_COUNT };
static const char *const opt_names[OPT_COUNT] = {"at", "--up", "--scale", "--name", "--yaw", "--size"};

/*
 * Parses the words of an import after FILE, or of a place after ID X Y Z:
 * the options in any order, each at most once ("at X Y Z" counts as one,
 * and only import takes it and the file options). Returns 0, or -1 with a
 * message that ends with the usage.
 */
static int parse_object_opts(char **w, int n, const char *usage, script_cmd *cmd, char *err, size_t errlen)
{
    const char *what = cmd->op == SCRIPT_IMPORT ? "import" : "place";
    unsigned seen = 0;
    for (int i = 0; i < n;) {
        int o = 0;
        while (o < OPT_COUNT && strcmp(opt_names[o], w[i]) != 0)
            o++;
        if (o == OPT_COUNT || (cmd->op == SCRIPT_PLACE && o < OPT_YAW)) {
            snprintf(err, errlen, "%s: unexpected '%.40s': %s", what, w[i], usage);
            return -1;
        }
        if (seen & 1u << o) {
            snprintf(err, errlen, "%s: '%s' given twice: %s", what, opt_names[o], usage);
            return -1;
        }
        seen |= 1u << o;
        int nv = o == OPT_AT ? 3 : 1;
        if (n - i - 1 < nv) {
            snprintf(err, errlen, "%s: '%s' needs %s: %s", what, opt_names[o], o == OPT_AT ? "X Y Z" : "a value",
                     usage);
            return -1;
        }
        const char *v = w[i + 1];
        double lo = OBJ_SCALE_MIN, hi = OBJ_SCALE_MAX;
        int ok = 1;
        switch (o) {
        case OPT_AT:
            lo = -COORD_MAX;
            hi = COORD_MAX;
            for (int k = 0; k < 3 && ok; k++) {
                v = w[i + 1 + k];
                ok = parse_number(v, lo, hi, &cmd->arg[k]) == 0;
            }
            break;
        case OPT_UP:
            if (strcmp(v, "y") == 0 || strcmp(v, "Y") == 0)
                cmd->up_axis = PROTO_UP_Y;
            else if (strcmp(v, "z") == 0 || strcmp(v, "Z") == 0)
                cmd->up_axis = PROTO_UP_Z;
            else {
                snprintf(err, errlen, "import: --up: bad axis '%.40s' (want y or z): %s", v, usage);
                return -1;
            }
            break;
        case OPT_NAME:
            if (!object_name_ok(v)) {
                snprintf(err, errlen,
                         "import: --name: bad name '%.40s' (want 1 to %u bytes of UTF-8, no control characters): %s",
                         v, PROTO_OBJECT_NAME_MAX, usage);
                return -1;
            }
            snprintf(cmd->name, sizeof cmd->name, "%s", v);
            break;
        case OPT_YAW:
            lo = -YAW_MAX_DEG;
            hi = YAW_MAX_DEG;
            ok = parse_number(v, lo, hi, &cmd->yaw_deg) == 0;
            cmd->has_yaw = 1;
            break;
        case OPT_SCALE:
            ok = parse_number(v, lo, hi, &cmd->unit_scale) == 0;
            break;
        default: /* OPT_SIZE */
            ok = parse_number(v, lo, hi, &cmd->size) == 0;
            cmd->has_size = 1;
            break;
        }
        if (!ok) {
            snprintf(err, errlen, "%s: %s: bad number '%.40s' (want a finite number in [%g, %g]): %s", what,
                     opt_names[o], v, lo, hi, usage);
            return -1;
        }
        i += 1 + nv;
    }
    if (cmd->op == SCRIPT_IMPORT && !(seen & 1u << OPT_AT)) {
        snprintf(err, errlen, "import: missing 'at X Y Z': %s", usage);
        return -1;
    }
    return 0;
}

/* import, place and remove; w[0] is the command. Returns 0 or -1. */
static int parse_object_cmd(char **w, int n, const char *usage, script_cmd *cmd, char *err, size_t errlen)
{
    cmd->yaw_deg = 0.0;
    cmd->size = 1.0;
    cmd->unit_scale = 1.0;
    cmd->up_axis = PROTO_UP_Y;
    if (cmd->op == SCRIPT_IMPORT) {
        if (n < 2 || w[1][0] == '\0') {
            snprintf(err, errlen, "import: expected a file: %s", usage);
            return -1;
        }
        if (parse_object_opts(w + 2, n - 2, usage, cmd, err, errlen) < 0)
            return -1;
        cmd->file = cvre_xmalloc(strlen(w[1]) + 1);
        strcpy(cmd->file, w[1]);
        return 0;
    }
    const char *what = cmd->op == SCRIPT_PLACE ? "place" : "remove";
    int fixed = cmd->op == SCRIPT_PLACE ? 5 : 2;
    if (n < fixed || (cmd->op == SCRIPT_REMOVE && n > fixed)) {
        snprintf(err, errlen, "%s: expected %s: %s", what, cmd->op == SCRIPT_PLACE ? "ID X Y Z" : "ID", usage);
        return -1;
    }
    if (parse_id(w[1], &cmd->object_id) < 0) {
        snprintf(err, errlen, "%s: bad object id '%.40s' (want 1 to %" PRIu32 "): %s", what, w[1], UINT32_MAX,
                 usage);
        return -1;
    }
    if (cmd->op == SCRIPT_REMOVE)
        return 0;
    for (int k = 0; k < 3; k++)
        if (parse_number(w[2 + k], -COORD_MAX, COORD_MAX, &cmd->arg[k]) < 0) {
            snprintf(err, errlen, "place: bad number '%.40s' (want a finite number in [%g, %g]): %s", w[2 + k],
                     -COORD_MAX, COORD_MAX, usage);
            return -1;
        }
    return parse_object_opts(w + 5, n - 5, usage, cmd, err, errlen);
}

int script_parse_line(const char *line, script_cmd *cmd, char *err, size_t errlen)
{
    char buf[SCRIPT_LINE_MAX + 1];
    size_t n = strlen(line);
    if (n > SCRIPT_LINE_MAX) {
        snprintf(err, errlen, "line longer than %d bytes", SCRIPT_LINE_MAX);
        return -1;
    }
    memcpy(buf, line, n + 1);

    char *tok[WORDS_MAX];
    int nt = split_words(buf, tok, err, errlen);
    if (nt <= 0)
        return nt;

    size_t k = 0;
    while (k < NCOMMANDS && strcmp(commands[k].name, tok[0]) != 0)
        k++;
    if (k == NCOMMANDS) {
        snprintf(err, errlen, "unknown command '%.40s' (move, walk, wait, ping, import, place, remove, quit)",
                 tok[0]);
        return -1;
    }
    *cmd = (script_cmd){.op = commands[k].op};
    if (commands[k].nargs < 0)
        return parse_object_cmd(tok, nt, commands[k].usage, cmd, err, errlen) < 0 ? -1 : 1;
    if (nt - 1 != commands[k].nargs) {
        snprintf(err, errlen, "%s: expected %d argument%s: %s", commands[k].name, commands[k].nargs,
                 commands[k].nargs == 1 ? "" : "s", commands[k].usage);
        return -1;
    }
    for (int i = 0; i < commands[k].nargs; i++) {
        double lo = -COORD_MAX, hi = COORD_MAX;
        if (cmd->op == SCRIPT_WAIT) {
            lo = 0.0;
            hi = WAIT_MAX_MS;
        } else if (cmd->op == SCRIPT_WALK && i == 2) {
            lo = 0.0;
            hi = WALK_MAX_S;
        }
        if (parse_number(tok[i + 1], lo, hi, &cmd->arg[i]) < 0) {
            snprintf(err, errlen, "%s: bad number '%.40s' (want a finite number in [%g, %g]): %s",
                     commands[k].name, tok[i + 1], lo, hi, commands[k].usage);
            return -1;
        }
    }
    return 1;
}

void script_cmd_clear(script_cmd *cmd)
{
    free(cmd->file);
    cmd->file = NULL;
}

/* ---- the runner -------------------------------------------------------- */

struct script {
    ev_loop *loop;
    session_ctx *ctx;
    session *c;
    double rate;
    uint64_t period_ns;
    const char *source; /* for messages: the file name or "stdin" */
    int exit_code;
    int quitting; /* we asked for the end; an end now is not a failure */

    /* Commands not run yet: q[q_head..q_len). */
    script_cmd *q;
    size_t q_len, q_cap, q_head;

    /* Standard input read as it comes. */
    int reading;
    int interactive;
    int input_done; /* no more commands will come */
    unsigned lineno;
    size_t line_len;
    char line[SCRIPT_LINE_MAX + 2]; /* one byte more than allowed, to see it is too long */

    /* The running command. */
    int running;
    script_cmd cur;
    int cmd_timer; /* -1 when none */
    uint64_t t_start;
    float target[3], base[3]; /* move: where to, and the last point sent */
    double best;              /* move: closest authoritative distance so far, */
    uint64_t t_best;          /* and since when */
    float from[3];            /* walk: start */
    unsigned walk_k, walk_n;  /* walk: moves sent, moves in all */
    uint32_t walk_seq;        /* walk: seq of the last move */
    uint64_t t_sent;          /* walk: when the last move went out */
    uint64_t ping_stamp;

    /* import: the upload of the running command */
    int imp_phase;      /* enum import_phase */
    int imp_fd;         /* the model file, -1 when closed */
    uint32_t imp_id;    /* its upload id */
    uint32_t imp_size;  /* bytes in all, */
    uint32_t imp_off;   /* and sent */
    uint32_t imp_acked; /* the server has read this far (window probes) */
    int imp_begun;      /* the server has read the BEGIN (its probe came back) */
    uint32_t imp_probe_at; /* next probe once imp_off reaches this */
    int imp_aborted;    /* the file failed mid-way; waiting for the server to drop the upload */
    uint64_t t_progress;
    uint32_t last_upload_id;
    uint8_t chunk[PROTO_CHUNK_MAX];

    /* Objects the server told us about, sorted by id, so that a place that
     * does not name a yaw or a size keeps the current ones. */
    struct known_object {
        uint32_t id;
        float yaw, scale;
    } *objs;
    size_t n_objs, cap_objs;

    int keepalive_timer;
    int linger_timer;
    int start_timer;
};

/* Where an import stands: its frames go out in this order, each only once
 * the backlog is empty, and then it waits for the server's answer. */
enum import_phase { IMPORT_NONE, IMPORT_BEGIN, IMPORT_CHUNKS, IMPORT_END, IMPORT_WAIT };

static void advance(script *s);
static ev_timer_fn on_cmd_timer;

static void fail(script *s, int code)
{
    if (code > s->exit_code)
        s->exit_code = code;
}

static double dist3(const float a[3], const float b[3])
{
    double dx = (double)a[0] - b[0], dy = (double)a[1] - b[1], dz = (double)a[2] - b[2];
    return sqrt(dx * dx + dy * dy + dz * dz);
}

static const char *op_name(int op)
{
    for (size_t k = 0; k < NCOMMANDS; k++)
        if (commands[k].op == op)
            return commands[k].name;
    return "?";
}

/* Lets go of what the running command holds (its timer, an import's file,
 * its strings); it is no longer running. */
static void cmd_release(script *s)
{
    session_timer_stop(s->loop, &s->cmd_timer);
    if (s->imp_fd >= 0) {
        close(s->imp_fd);
        s->imp_fd = -1;
    }
    s->imp_phase = IMPORT_NONE;
    s->imp_id = 0;
    s->imp_aborted = 0;
    script_cmd_clear(&s->cur);
    s->running = 0;
}

/* Ends the running command; move, walk and wait report where we are. */
static void cmd_done(script *s)
{
    if (s->cur.op == SCRIPT_MOVE || s->cur.op == SCRIPT_WALK || s->cur.op == SCRIPT_WAIT)
        events_done(op_name(s->cur.op), session_get_view(s->c)->pos);
    cmd_release(s);
}

static void cmd_finish(script *s)
{
    cmd_done(s);
    advance(s);
}

/* Ends the running import, place or remove with its done event (result as
 * events_done_object() takes it) without advancing; for an import,
 * object_id is the object it made, 0 if none. */
static void obj_done(script *s, const char *result, uint32_t object_id)
{
    double secs = (double)(ev_now(s->loop) - s->t_start) / (double)NS_PER_S;
    if (s->cur.op == SCRIPT_IMPORT)
        events_done_object("import", result, object_id, s->imp_id, secs);
    else
        events_done_object(op_name(s->cur.op), result, s->cur.object_id, 0, secs);
    cmd_release(s);
}

static void obj_finish(script *s, const char *result, uint32_t object_id)
{
    obj_done(s, result, object_id);
    advance(s);
}

/* A local failure of an object command: an error event with code 0 (as for
 * the client's other own errors), the same text on stderr for whoever
 * watches the terminal. The command then ends as "failed". */
__attribute__((format(printf, 1, 2))) static void obj_error(const char *fmt, ...)
{
    char text[PROTO_MESSAGE_MAX + 100];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    log_warn("%s", text);
    events_error(-1, 0, text, strlen(text));
}

/* ---- known objects ----------------------------------------------------- */

/* Index of the first entry whose id is >= id. */
static size_t objects_at(const script *s, uint32_t id)
{
    size_t lo = 0, hi = s->n_objs;
    while (lo < hi) {
        size_t mid = lo + (hi - lo) / 2;
        if (s->objs[mid].id < id)
            lo = mid + 1;
        else
            hi = mid;
    }
    return lo;
}

static const struct known_object *objects_get(const script *s, uint32_t id)
{
    size_t i = objects_at(s, id);
    return i < s->n_objs && s->objs[i].id == id ? &s->objs[i] : NULL;
}

static void objects_put(script *s, uint32_t id, float yaw, float scale)
{
    size_t i = objects_at(s, id);
    if (i == s->n_objs || s->objs[i].id != id) {
        if (s->n_objs == s->cap_objs) {
            s->cap_objs = s->cap_objs ? s->cap_objs * 2 : 64;
            s->objs = cvre_xrealloc(s->objs, s->cap_objs * sizeof *s->objs);
        }
        memmove(s->objs + i + 1, s->objs + i, (s->n_objs - i) * sizeof *s->objs);
        s->n_objs++;
    }
    s->objs[i] = (struct known_object){id, yaw, scale};
}

static void objects_del(script *s, uint32_t id)
{
    size_t i = objects_at(s, id);
    if (i < s->n_objs && s->objs[i].id == id) {
        memmove(s->objs + i, s->objs + i + 1, (s->n_objs - i - 1) * sizeof *s->objs);
        s->n_objs--;
    }
}

/* ---- import ------------------------------------------------------------ */

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

/* Yaw in radians from degrees, reduced to one turn first so that a large
 * angle loses nothing in the f32. */
static float yaw_radians(double deg) { return (float)(fmod(deg, 360.0) * (PI / 180.0)); }

/*
 * Ends an upload the file failed in the middle of. The server holds one
 * upload per connection until it is complete, so it is ended early: an
 * OBJECT_UPLOAD_END short of the announced size makes the server drop it
 * and say so, and the import is over ("failed") when that rejection comes.
 * Returns 0 while waiting for it, -1 if even that could not be sent.
 */
static int import_abort(script *s)
{
    proto_upload_end e = {.upload_id = s->imp_id, .at = {.scale = 1.0f}};
    if (session_send_upload_end(s->c, &e) < 0)
        return -1;
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
 * call to go on. Returns 0, or -1 after reporting a local read failure (the
 * caller ends the command). A session that cannot send any more is left to
 * on_close, which ends the run.
 */
static int import_pump(script *s)
{
    for (int budget = IMPORT_FRAMES_PER_WAKEUP; s->imp_phase != IMPORT_WAIT; budget--) {
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
                obj_error("import: cannot read %s: %s", s->cur.file,
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
                                         .yaw = yaw_radians(s->cur.yaw_deg), .scale = (float)s->cur.size}};
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

/* The pong of a window probe (not printed: nobody asked for it). Opens
 * the window up to the offset it carries and goes on sending. */
static void import_probed(script *s, uint64_t stamp)
{
    uint32_t off = (uint32_t)stamp;
    if (!s->running || s->cur.op != SCRIPT_IMPORT || s->imp_phase != IMPORT_CHUNKS ||
        stamp != probe_stamp(s, off) || off > s->imp_off || (s->imp_begun && off <= s->imp_acked))
        return;
    s->imp_begun = 1;
    s->imp_acked = off;
    s->t_progress = ev_now(s->loop);
    if (session_out_pending(s->c) == 0 && import_pump(s) < 0)
        obj_finish(s, "failed", 0);
}

/*
 * Starts an import: opens and checks the file, then sends what it can. A
 * file that cannot be read is an error event and the command ends at once
 * ("failed"), the script goes on. Returns 1 if the command is still
 * running, 0 if it ended here.
 */
static int import_start(script *s)
{
    const char *file = s->cur.file;
    struct stat st;
    s->imp_fd = open(file, O_RDONLY | O_CLOEXEC | O_NONBLOCK); /* a FIFO must not block us */
    if (s->imp_fd < 0 || fstat(s->imp_fd, &st) < 0) {
        obj_error("import: cannot read %s: %s", file, strerror(errno));
    } else if (!S_ISREG(st.st_mode)) {
        obj_error("import: cannot read %s: not a regular file", file);
    } else if (st.st_size == 0) {
        obj_error("import: cannot read %s: the file is empty", file);
    } else if ((unsigned long long)st.st_size > IMPORT_FILE_MAX) {
        obj_error("import: cannot read %s: %lld bytes, over the limit of %llu bytes", file,
                  (long long)st.st_size, (unsigned long long)IMPORT_FILE_MAX);
    } else {
        if (++s->last_upload_id == 0)
            s->last_upload_id = 1;
        s->imp_id = s->last_upload_id;
        s->imp_size = (uint32_t)st.st_size;
        s->imp_off = s->imp_acked = 0;
        s->imp_begun = 0;
        s->imp_probe_at = IMPORT_PROBE_BYTES;
        s->imp_phase = IMPORT_BEGIN;
        s->t_progress = ev_now(s->loop);
        s->cmd_timer = session_timer_start(s->loop, IMPORT_CHECK_NS, IMPORT_CHECK_NS, on_cmd_timer, s);
        if (import_pump(s) == 0)
            return 1;
    }
    obj_done(s, "failed", 0);
    return 0;
}

static void on_linger(ev_loop *loop, void *data)
{
    script *s = data;
    (void)loop;
    s->linger_timer = -1;
    session_close(s->c);
}

/* Says bye and gives the server QUIT_LINGER_NS to close; abandons any
 * running command. */
static void quit(script *s)
{
    if (s->quitting)
        return;
    s->quitting = 1;
    cmd_release(s);
    if (session_bye(s->c, PROTO_BYE_QUIT))
        events_bye_sent(PROTO_BYE_QUIT);
    s->linger_timer = session_timer_start(s->loop, QUIT_LINGER_NS, 0, on_linger, s);
}

/* One step of a move: the next point on the straight line from the last
 * point sent, max_speed / rate further, never past the target. Stepping
 * from what we sent rather than from the authoritative position keeps the
 * requests ahead of the server by the round trip instead of dragging it
 * back; once the target is reached it is sent again until the server
 * arrives or gives up. */
static void move_step(script *s)
{
    double step = session_get_view(s->c)->welcome.max_speed / s->rate;
    double d = dist3(s->target, s->base);
    float next[3];
    for (int i = 0; i < 3; i++)
        next[i] = d <= step ? s->target[i] : (float)(s->base[i] + (s->target[i] - s->base[i]) * (step / d));
    if (session_send_move(s->c, next))
        memcpy(s->base, next, sizeof next);
}

/* True when the move is over: arrived, stalled or out of time. */
static int move_over(script *s, uint64_t now)
{
    double d = dist3(session_get_view(s->c)->pos, s->target);
    if (d <= MOVE_REACHED_M)
        return 1;
    if (d < s->best - MOVE_PROGRESS_M) {
        s->best = d;
        s->t_best = now;
    }
    return now - s->t_best >= MOVE_STALL_NS || now - s->t_start >= MOVE_TIMEOUT_NS;
}

static void walk_step(script *s, uint64_t now)
{
    if (s->walk_k == s->walk_n)
        return;
    double f = (double)(s->walk_k + 1) / s->walk_n;
    float next[3] = {(float)(s->from[0] + f * s->cur.arg[0]), s->from[1],
                     (float)(s->from[2] + f * s->cur.arg[1])};
    uint32_t seq = session_send_move(s->c, next);
    if (!seq)
        return; /* backlog full: the same point again next period */
    if (++s->walk_k == s->walk_n) {
        s->walk_seq = seq;
        s->t_sent = now;
    }
}

static int walk_over(const script *s, uint64_t now)
{
    return s->walk_k == s->walk_n &&
           (session_get_view(s->c)->ack >= s->walk_seq || now - s->t_sent >= WALK_ACK_WAIT_NS);
}

/* Paces move and walk at the rate; ends wait and ping when they run out. */
static void on_cmd_timer(ev_loop *loop, void *data)
{
    script *s = data;
    uint64_t now = ev_now(loop);
    switch (s->cur.op) {
    case SCRIPT_MOVE:
        if (move_over(s, now))
            cmd_finish(s);
        else
            move_step(s);
        break;
    case SCRIPT_WALK:
        if (walk_over(s, now))
            cmd_finish(s);
        else
            walk_step(s, now);
        break;
    case SCRIPT_PING:
        log_warn("no pong within %llu s", PING_WAIT_NS / NS_PER_S);
        s->cmd_timer = -1; /* one-shot: fired, its id may be reused */
        cmd_finish(s);
        break;
    case SCRIPT_IMPORT:
        if (now - s->t_progress >= IMPORT_TIMEOUT_NS) {
            log_warn("import of %s: %s for %llu s; giving up", s->cur.file,
                     s->imp_phase == IMPORT_WAIT ? "no answer from the server" : "could not send",
                     (unsigned long long)(IMPORT_TIMEOUT_NS / NS_PER_S));
            obj_finish(s, s->imp_aborted ? "failed" : "timeout", 0);
        }
        break;
    case SCRIPT_PLACE:
    case SCRIPT_REMOVE:
        log_warn("%s %" PRIu32 ": no answer within %llu s", op_name(s->cur.op), s->cur.object_id,
                 OBJECT_WAIT_NS / NS_PER_S);
        s->cmd_timer = -1;
        obj_finish(s, "timeout", 0);
        break;
    default: /* wait */
        s->cmd_timer = -1;
        cmd_finish(s);
        break;
    }
}

/* Starts cmd; a command that is over at once (a move to where we are, a
 * failed ping) ends here without advancing, which advance() does. */
static void cmd_start(script *s, const script_cmd *cmd)
{
    const session_view *v = session_get_view(s->c);
    uint64_t now = ev_now(s->loop);
    s->cur = *cmd;
    s->running = 1;
    s->t_start = now;
    switch (cmd->op) {
    case SCRIPT_MOVE:
        for (int i = 0; i < 3; i++)
            s->target[i] = (float)cmd->arg[i];
        memcpy(s->base, v->pos, sizeof s->base);
        s->best = dist3(v->pos, s->target);
        s->t_best = now;
        if (s->best <= MOVE_REACHED_M) {
            cmd_done(s);
            return;
        }
        move_step(s);
        s->cmd_timer = session_timer_start(s->loop, s->period_ns, s->period_ns, on_cmd_timer, s);
        break;
    case SCRIPT_WALK: {
        double n = round(cmd->arg[2] * s->rate);
        memcpy(s->from, v->pos, sizeof s->from);
        s->walk_k = 0;
        s->walk_n = n < 1.0 ? 1u : (unsigned)n;
        walk_step(s, now);
        s->cmd_timer = session_timer_start(s->loop, s->period_ns, s->period_ns, on_cmd_timer, s);
        break;
    }
    case SCRIPT_WAIT:
        s->cmd_timer = session_timer_start(s->loop, (uint64_t)(cmd->arg[0] * (double)NS_PER_MS), 0, on_cmd_timer, s);
        break;
    case SCRIPT_PING:
        s->ping_stamp = ev_clock(s->loop) / 1000u;
        if (session_send_ping(s->c, s->ping_stamp) < 0) {
            log_warn("ping not sent: output backlog full");
            cmd_release(s);
            return;
        }
        s->cmd_timer = session_timer_start(s->loop, PING_WAIT_NS, 0, on_cmd_timer, s);
        break;
    case SCRIPT_IMPORT:
        import_start(s);
        break;
    case SCRIPT_PLACE: {
        const struct known_object *k = objects_get(s, cmd->object_id);
        proto_object_place p = {.object_id = cmd->object_id,
                                .at = {.pos = {(float)cmd->arg[0], (float)cmd->arg[1], (float)cmd->arg[2]},
                                       .yaw = cmd->has_yaw ? yaw_radians(cmd->yaw_deg) : k ? k->yaw : 0.0f,
                                       .scale = cmd->has_size ? (float)cmd->size : k ? k->scale : 1.0f}};
        int rc = session_send_object_place(s->c, &p);
        if (rc < 0) {
            obj_error("place %" PRIu32 ": not sent: %s", cmd->object_id, strerror(-rc));
            obj_done(s, "failed", 0);
            return;
        }
        s->cmd_timer = session_timer_start(s->loop, OBJECT_WAIT_NS, 0, on_cmd_timer, s);
        break;
    }
    case SCRIPT_REMOVE: {
        int rc = session_send_object_remove(s->c, cmd->object_id);
        if (rc < 0) {
            obj_error("remove %" PRIu32 ": not sent: %s", cmd->object_id, strerror(-rc));
            obj_done(s, "failed", 0);
            return;
        }
        s->cmd_timer = session_timer_start(s->loop, OBJECT_WAIT_NS, 0, on_cmd_timer, s);
        break;
    }
    default:
        s->running = 0;
        quit(s);
        break;
    }
}

/* Runs queued commands while none is running and we are joined; quits when
 * the input is over and the queue empty. */
static void advance(script *s)
{
    while (!s->running && !s->quitting && session_state(s->c) == SESSION_JOINED) {
        if (s->q_head == s->q_len) {
            if (s->input_done)
                quit(s);
            return;
        }
        script_cmd cmd = s->q[s->q_head++];
        if (s->q_head == s->q_len)
            s->q_head = s->q_len = 0;
        cmd_start(s, &cmd);
    }
}

static void on_start(ev_loop *loop, void *data)
{
    script *s = data;
    (void)loop;
    s->start_timer = -1;
    advance(s);
}

static void on_msg(session *c, const proto_msg *m, void *data)
{
    script *s = data;
    const session_view *v = session_get_view(c);
    uint64_t now = ev_clock(s->loop);
    if (m->type == PROTO_PONG && (m->u.ping.stamp & IMPORT_PROBE_MARK)) {
        import_probed(s, m->u.ping.stamp);
        return;
    }
    events_message(m, now / 1000u);
    switch (m->type) {
    case PROTO_JOIN_OK:
        /* The world's objects follow the join; letting them in first (the
         * rest of this read, at least) gives a first place command the
         * current yaw and size to keep. */
        s->start_timer = session_timer_start(s->loop, 0, 0, on_start, s);
        break;
    case PROTO_SNAPSHOT:
        if (!s->running)
            break;
        if ((s->cur.op == SCRIPT_MOVE && v->pos_fresh && move_over(s, now)) ||
            (s->cur.op == SCRIPT_WALK && walk_over(s, now)))
            cmd_finish(s);
        break;
    case PROTO_PONG:
        if (s->running && s->cur.op == SCRIPT_PING && m->u.ping.stamp == s->ping_stamp)
            cmd_finish(s);
        break;
    case PROTO_ERROR:
        fail(s, 1);
        break;
    case PROTO_OBJECT_INFO: {
        const proto_object_info *o = &m->u.object_info;
        objects_put(s, o->object_id, o->at.yaw, o->at.scale);
        if (!s->running)
            break;
        if (s->cur.op == SCRIPT_IMPORT && s->imp_phase != IMPORT_NONE && o->upload_id == s->imp_id)
            obj_finish(s, "ok", o->object_id);
        else if (s->cur.op == SCRIPT_PLACE && o->object_id == s->cur.object_id)
            obj_finish(s, "ok", o->object_id);
        break;
    }
    case PROTO_OBJECT_REMOVED:
        objects_del(s, m->u.object_id);
        if (s->running && s->cur.op == SCRIPT_REMOVE && m->u.object_id == s->cur.object_id)
            obj_finish(s, "ok", 0);
        break;
    case PROTO_OBJECT_REJECTED: {
        uint32_t id = m->u.object_rejected.request_id;
        if (s->running && ((s->cur.op == SCRIPT_IMPORT && s->imp_phase != IMPORT_NONE && id == s->imp_id) ||
                           ((s->cur.op == SCRIPT_PLACE || s->cur.op == SCRIPT_REMOVE) && id == s->cur.object_id)))
            obj_finish(s, s->imp_aborted ? "failed" : "rejected", 0);
        break;
    }
    default:
        break;
    }
}

/* Asked for by import_pump(): the backlog has drained. */
static void on_writable(session *c, void *data)
{
    script *s = data;
    (void)c;
    if (s->running && s->cur.op == SCRIPT_IMPORT && s->imp_phase != IMPORT_NONE && s->imp_phase != IMPORT_WAIT &&
        import_pump(s) < 0)
        obj_finish(s, "failed", 0);
}

static void on_close(session *c, const session_end *end, void *data)
{
    script *s = data;
    (void)c;
    if (events_conn_end(-1, end, session_ctx_peer(s->ctx)))
        fail(s, 1);
    events_closed(-1);
    if (!s->quitting)
        fail(s, 1);
    cmd_release(s);
    session_timer_stop(s->loop, &s->linger_timer);
    session_timer_stop(s->loop, &s->start_timer);
    ev_stop(s->loop);
}

static const session_handler handler = {.on_msg = on_msg, .on_close = on_close, .on_writable = on_writable};

static void on_keepalive(ev_loop *loop, void *data)
{
    script *s = data;
    (void)loop;
    session_keepalive(s->c);
}

/* ---- input ------------------------------------------------------------- */

static void push(script *s, const script_cmd *cmd)
{
    if (s->q_len == s->q_cap) {
        s->q_cap = s->q_cap ? s->q_cap * 2 : 16;
        s->q = cvre_xrealloc(s->q, s->q_cap * sizeof *s->q);
    }
    s->q[s->q_len++] = *cmd;
}

/* Parses one line and queues its command. Returns 0, or -1 after printing
 * the error (naming the line) on stderr. */
static int take_line(script *s, const char *line)
{
    script_cmd cmd;
    char err[512];
    int rc = script_parse_line(line, &cmd, err, sizeof err);
    s->lineno++;
    if (rc < 0) {
        fprintf(stderr, "cvre-client: %s:%u: %s\n", s->source, s->lineno, err);
        return -1;
    }
    if (rc == 1)
        push(s, &cmd);
    return 0;
}

/*
 * Reads a whole script from f before anything runs, so a mistake on line 90
 * costs nothing but the message. Returns 0, 2 for a bad line, 1 for a read
 * error.
 */
static int load(script *s, FILE *f)
{
    char *line = NULL;
    size_t cap = 0;
    ssize_t n;
    int rc = 0;
    while ((n = getline(&line, &cap, f)) >= 0) {
        if (n > 0 && line[n - 1] == '\n')
            line[n - 1] = '\0';
        if (take_line(s, line) < 0) {
            rc = 2;
            break;
        }
    }
    if (rc == 0 && ferror(f)) {
        fprintf(stderr, "cvre-client: reading %s: %s\n", s->source, strerror(errno));
        rc = 1;
    }
    free(line);
    s->input_done = 1;
    return rc;
}

static void prompt(const script *s)
{
    if (s->interactive && !s->input_done) {
        fputs("> ", stderr);
        fflush(stderr);
    }
}

static void input_over(script *s)
{
    if (s->reading) {
        ev_io_del(s->loop, STDIN_FILENO);
        s->reading = 0;
    }
    s->input_done = 1;
}

/* A complete line from streamed input. Interactively a bad line is only
 * reported; in a piped script it ends the run with exit code 2. */
static void stream_line(script *s)
{
    s->line[s->line_len] = '\0';
    s->line_len = 0;
    if (take_line(s, s->line) < 0 && !s->interactive) {
        fail(s, 2);
        input_over(s);
        quit(s);
        return;
    }
    prompt(s);
}

/* Standard input is readable: a pipe or a terminal, read as it comes. The
 * fd stays blocking (it is shared with the shell); one read after a
 * readiness report does not block. */
static void on_input(ev_loop *loop, int fd, unsigned events, void *data)
{
    script *s = data;
    char buf[4096];
    (void)loop;
    (void)events;
    ssize_t n = read(fd, buf, sizeof buf);
    if (n < 0) {
        if (errno == EINTR || errno == EAGAIN)
            return;
        log_error("reading stdin: %s", strerror(errno));
        n = 0;
    }
    if (n == 0) {
        if (s->line_len > 0)
            stream_line(s);
        input_over(s);
        if (s->interactive)
            fputs("\n", stderr);
        advance(s);
        return;
    }
    for (ssize_t i = 0; i < n && s->reading; i++) {
        if (buf[i] == '\n')
            stream_line(s);
        else if (s->line_len < sizeof s->line - 1)
            s->line[s->line_len++] = buf[i]; /* past the limit only the length matters */
    }
    advance(s);
}

/* ---- public ------------------------------------------------------------ */

script *script_create(ev_loop *loop, const script_opts *o, int *exit_code)
{
    script *s = cvre_xcalloc(1, sizeof *s);
    s->loop = loop;
    s->rate = o->rate;
    s->period_ns = (uint64_t)((double)NS_PER_S / o->rate);
    s->cmd_timer = s->keepalive_timer = s->linger_timer = s->start_timer = -1;
    s->imp_fd = -1;
    s->source = o->file ? o->file : "stdin";

    int rc = 0;
    if (o->file) {
        FILE *f = fopen(o->file, "r");
        if (!f) {
            fprintf(stderr, "cvre-client: cannot open script %s: %s\n", o->file, strerror(errno));
            rc = 2;
        } else {
            rc = load(s, f);
            fclose(f);
        }
    } else {
        s->interactive = isatty(STDIN_FILENO);
        int r = ev_io_add(loop, STDIN_FILENO, EV_READ, on_input, s);
        if (r == 0)
            s->reading = 1;
        else if (r == -EPERM) /* a regular file or /dev/null: epoll cannot watch it */
            rc = load(s, stdin);
        else {
            fprintf(stderr, "cvre-client: cannot watch stdin: %s\n", strerror(-r));
            rc = 1;
        }
    }
    if (rc != 0) {
        *exit_code = rc;
        script_free(s);
        return NULL;
    }

    char err[512];
    s->ctx = session_ctx_create(loop, o->net.host, o->net.port, err, sizeof err);
    if (!s->ctx) {
        fprintf(stderr, "cvre-client: %s\n", err);
        *exit_code = 1;
        script_free(s);
        return NULL;
    }
    s->c = session_open(s->ctx, o->net.name, o->net.box, &handler, s);
    session_set_credential(s->c, &o->login);
    s->keepalive_timer = session_timer_start(s->loop, KEEPALIVE_CHECK_NS, KEEPALIVE_CHECK_NS, on_keepalive, s);
    prompt(s);
    return s;
}

void script_interrupt(script *s)
{
    input_over(s);
    if (s->quitting)
        session_close(s->c);
    else
        quit(s);
}

int script_exit_code(const script *s) { return s->exit_code; }

void script_free(script *s)
{
    if (!s)
        return;
    input_over(s);
    cmd_release(s);
    session_timer_stop(s->loop, &s->keepalive_timer);
    session_timer_stop(s->loop, &s->linger_timer);
    session_timer_stop(s->loop, &s->start_timer);
    session_free(s->c);
    session_ctx_free(s->ctx);
    for (size_t i = s->q_head; i < s->q_len; i++)
        script_cmd_clear(&s->q[i]);
    free(s->q);
    free(s->objs);
    free(s);
}
