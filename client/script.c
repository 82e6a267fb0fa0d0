/*
 * script.c: the runner of the scripted and interactive client (see
 * script.h): commands queued from a file or standard input, run one at a
 * time once joined (move, walk, wait, ping, place, remove, quit; imports in
 * script_upload.c), every message from the server printed as it comes.
 */
#include "scriptInt.h"

#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"
#include "events.h"
#include "log.h"
#include "terminal.h"

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

static void advance(script *s);

/* The run ends with the worst exit code it met (script_exit_code()). */
static void raise_exit_code(script *s, int code)
{
    if (code > s->exit_code)
        s->exit_code = code;
}

static double dist3(const float a[3], const float b[3])
{
    double dx = (double)a[0] - b[0], dy = (double)a[1] - b[1], dz = (double)a[2] - b[2];
    return sqrt(dx * dx + dy * dy + dz * dz);
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
    s->imp_object = 0;
    s->imp_aborted = 0;
    script__fetch_release(s);
    script_cmd_clear(&s->cur);
    s->running = 0;
}

/* Ends the running command; move, walk and wait report where we are. */
static void cmd_done(script *s)
{
    if (s->cur.op == SCRIPT_MOVE || s->cur.op == SCRIPT_WALK || s->cur.op == SCRIPT_WAIT || s->cur.op == SCRIPT_POSE)
        events_done(script_op_name(s->cur.op), session_get_view(s->c)->pos);
    cmd_release(s);
}

static void cmd_finish(script *s)
{
    cmd_done(s);
    advance(s);
}

void script__obj_done(script *s, const char *result, const proto_object_info *o)
{
    double secs = (double)(ev_now(s->loop) - s->t_start) / (double)NS_PER_S;
    float box[6];
    const float *where = o && known_bounds(o, box, box + 3) == 0 ? box : NULL;
    if (s->cur.op == SCRIPT_IMPORT)
        events_done_object("import", result, s->imp_object, s->imp_id, secs, where);
    else
        events_done_object(script_op_name(s->cur.op), result, s->cur.object_id, 0, secs, where);
    cmd_release(s);
}

void script__obj_finish(script *s, const char *result, const proto_object_info *o)
{
    script__obj_done(s, result, o);
    advance(s);
}

void script__obj_error(const script *s, const char *fmt, ...)
{
    char text[PROTO_MESSAGE_MAX + 100];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(text, sizeof text, fmt, ap);
    va_end(ap);
    if (!s->terminal)
        log_warn("%s", text);
    events_error(-1, 0, text, strlen(text));
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

/* Paces move and walk at the rate; ends wait and ping when they run out,
 * and object commands that waited too long. */
void script__on_cmd_timer(ev_loop *loop, void *data)
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
        script__import_check(s, now);
        break;
    case SCRIPT_FETCH:
        script__fetch_check(s, now);
        break;
    case SCRIPT_PLACE:
    case SCRIPT_REMOVE:
        log_warn("%s %" PRIu32 ": no answer within %llu s", script_op_name(s->cur.op), s->cur.object_id,
                 OBJECT_WAIT_NS / NS_PER_S);
        s->cmd_timer = -1;
        script__obj_finish(s, "timeout", NULL);
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
        s->cmd_timer = session_timer_start(s->loop, s->period_ns, s->period_ns, script__on_cmd_timer, s);
        break;
    case SCRIPT_WALK: {
        double n = round(cmd->arg[2] * s->rate);
        memcpy(s->from, v->pos, sizeof s->from);
        s->walk_k = 0;
        s->walk_n = n < 1.0 ? 1u : (unsigned)n;
        walk_step(s, now);
        s->cmd_timer = session_timer_start(s->loop, s->period_ns, s->period_ns, script__on_cmd_timer, s);
        break;
    }
    case SCRIPT_WAIT:
        s->cmd_timer = session_timer_start(s->loop, (uint64_t)(cmd->arg[0] * (double)NS_PER_MS), 0, script__on_cmd_timer, s);
        break;
    case SCRIPT_POSE: /* the facing sticks to the moves that follow; this one says it standing */
        session_set_facing(s->c, script__yaw_radians(cmd->arg[0]), (float)(cmd->arg[1] * (M_PI / 180.0)), 1);
        if (!session_send_move(s->c, v->pos))
            log_warn("pose not sent: output backlog full");
        cmd_done(s);
        return;
    case SCRIPT_PING:
        s->ping_stamp = ev_clock(s->loop) / 1000u;
        if (session_send_ping(s->c, s->ping_stamp) < 0) {
            log_warn("ping not sent: output backlog full");
            cmd_release(s);
            return;
        }
        s->cmd_timer = session_timer_start(s->loop, PING_WAIT_NS, 0, script__on_cmd_timer, s);
        break;
    case SCRIPT_IMPORT:
        script__import_start(s);
        break;
    case SCRIPT_FETCH:
        script__fetch_start(s);
        break;
    case SCRIPT_PLACE: {
        const known_object *k = known_get(s->objs, cmd->object_id);
        proto_object_place p = {.object_id = cmd->object_id,
                                .at = {.pos = {(float)cmd->arg[0], (float)cmd->arg[1], (float)cmd->arg[2]},
                                       .yaw = cmd->has_yaw ? script__yaw_radians(cmd->yaw_deg) : k ? k->yaw : 0.0f,
                                       .scale = cmd->has_size ? (float)cmd->size : k ? k->scale : 1.0f}};
        int rc = session_send_object_place(s->c, &p);
        if (rc < 0) {
            script__obj_error(s, "place %" PRIu32 ": not sent: %s", cmd->object_id, strerror(-rc));
            script__obj_done(s, "failed", NULL);
            return;
        }
        s->cmd_timer = session_timer_start(s->loop, OBJECT_WAIT_NS, 0, script__on_cmd_timer, s);
        break;
    }
    case SCRIPT_REMOVE: {
        int rc = session_send_object_remove(s->c, cmd->object_id);
        if (rc < 0) {
            script__obj_error(s, "remove %" PRIu32 ": not sent: %s", cmd->object_id, strerror(-rc));
            script__obj_done(s, "failed", NULL);
            return;
        }
        s->cmd_timer = session_timer_start(s->loop, OBJECT_WAIT_NS, 0, script__on_cmd_timer, s);
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

/* The request id an OBJECT_REJECTED for the running command names, 0 when
 * none is awaited: an import's upload id, then, while the import moves its
 * object to its anchor, the object id, as for place and remove. */
static uint32_t awaited_request(const script *s)
{
    if (!s->running)
        return 0;
    if (s->cur.op == SCRIPT_IMPORT)
        return s->imp_phase == IMPORT_SETTLE ? s->imp_object : s->imp_phase != IMPORT_NONE ? s->imp_id : 0;
    return s->cur.op == SCRIPT_PLACE || s->cur.op == SCRIPT_REMOVE || s->cur.op == SCRIPT_FETCH ? s->cur.object_id : 0;
}

static void on_msg(session *c, const proto_msg *m, void *data)
{
    script *s = data;
    const session_view *v = session_get_view(c);
    uint64_t now = ev_clock(s->loop);
    if (m->type == PROTO_PONG && (m->u.ping.stamp & IMPORT_PROBE_MARK)) {
        script__import_probed(s, m->u.ping.stamp);
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
        raise_exit_code(s, 1);
        break;
    case PROTO_OBJECT_INFO: {
        const proto_object_info *o = &m->u.object_info;
        known_put(s->objs, o);
        if (!s->running)
            break;
        if (s->cur.op == SCRIPT_IMPORT)
            script__import_object(s, o);
        else if (s->cur.op == SCRIPT_PLACE && o->object_id == s->cur.object_id)
            script__obj_finish(s, "ok", o);
        break;
    }
    case PROTO_OBJECT_REMOVED:
        known_del(s->objs, m->u.object_id);
        if (s->running && s->cur.op == SCRIPT_REMOVE && m->u.object_id == s->cur.object_id)
            script__obj_finish(s, "ok", NULL);
        break;
    case PROTO_MESH_CHUNK:
        if (s->running && s->cur.op == SCRIPT_FETCH)
            script__fetch_chunk(s, &m->u.mesh_chunk);
        break;
    case PROTO_OBJECT_REJECTED: {
        uint32_t want = awaited_request(s);
        if (want != 0 && m->u.object_rejected.request_id == want)
            script__obj_finish(s, s->imp_aborted ? "failed" : "rejected", NULL);
        break;
    }
    default:
        break;
    }
}

/* Asked for by script__import_pump(): the backlog has drained. */
static void on_writable(session *c, void *data)
{
    script *s = data;
    (void)c;
    if (s->running && s->cur.op == SCRIPT_IMPORT && script__import_pump(s) < 0)
        script__obj_finish(s, "failed", NULL);
}

static void on_close(session *c, const session_end *end, void *data)
{
    script *s = data;
    (void)c;
    if (s->terminal)
        terminal_prompt(NULL); /* nothing more will be read */
    if (events_conn_end(-1, end, session_ctx_peer(s->ctx)))
        raise_exit_code(s, 1);
    events_closed(-1);
    if (!s->quitting)
        raise_exit_code(s, 1);
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

/* Parses one line and queues its command. Returns 0, or -EINVAL after
 * printing the error (naming the line) on stderr. */
static int take_line(script *s, const char *line)
{
    script_cmd cmd;
    char err[512];
    int rc = script_parse_line(line, &cmd, err, sizeof err);
    s->lineno++;
    if (rc < 0) {
        fprintf(stderr, "cvre-client: %s:%u: %s\n", s->source, s->lineno, err);
        return rc;
    }
    if (rc == 1)
        push(s, &cmd);
    return 0;
}

/*
 * Reads a whole script from f before anything runs, so a mistake on line 90
 * costs nothing but the message. Returns 0, -EINVAL for a bad line or -EIO
 * for a read error, each reported on stderr.
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
        rc = take_line(s, line);
        if (rc < 0)
            break;
    }
    if (rc == 0 && ferror(f)) {
        fprintf(stderr, "cvre-client: reading %s: %s\n", s->source, strerror(errno));
        rc = -EIO;
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
    if (s->terminal)
        terminal_prompt(NULL);
}

/* A complete line from streamed input. Interactively a bad line is only
 * reported; in a piped script it ends the run with exit code 2. */
static void stream_line(script *s)
{
    s->line[s->line_len] = '\0';
    s->line_len = 0;
    if (take_line(s, s->line) < 0 && !s->interactive) {
        raise_exit_code(s, 2);
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
    s->objs = known_create();

    int rc = 0;
    if (o->file) {
        FILE *f = fopen(o->file, "r");
        if (!f) {
            fprintf(stderr, "cvre-client: cannot open script %s: %s\n", o->file, strerror(errno));
            rc = -EINVAL; /* a --script that names no readable file: a usage error */
        } else {
            rc = load(s, f);
            fclose(f);
        }
    } else {
        s->interactive = isatty(STDIN_FILENO);
        /* A person at a terminal: the lines a person reads, unless --json. */
        s->terminal = s->interactive && !o->json && isatty(STDOUT_FILENO);
        if (s->terminal) {
            events_to_terminal(1);
            terminal_prompt("> ");
        }
        int r = ev_io_add(loop, STDIN_FILENO, EV_READ, on_input, s);
        if (r == 0)
            s->reading = 1;
        else if (r == -EPERM) /* a regular file or /dev/null: epoll cannot watch it */
            rc = load(s, stdin);
        else {
            fprintf(stderr, "cvre-client: cannot watch stdin: %s\n", strerror(-r));
            rc = r;
        }
    }
    if (rc < 0) {
        *exit_code = rc == -EINVAL ? 2 : 1; /* a bad script, or one that could not be read */
        script_free(s);
        return NULL;
    }

    char err[512];
    s->ctx = session_ctx_create(loop, &o->net, err, sizeof err);
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
    known_free(s->objs);
    script__fetch_free_cache(s);
    free(s);
}
