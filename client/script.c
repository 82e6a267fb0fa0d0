/* script.c: the scripted and interactive client (see script.h). */
#include "script.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/types.h>
#include <unistd.h>

#include "alloc.h"
#include "events.h"
#include "log.h"

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

/* ---- parsing ----------------------------------------------------------- */

static const struct {
    const char *name;
    int op;
    int nargs;
    const char *usage;
} commands[] = {
    {"move", SCRIPT_MOVE, 3, "move X Y Z"},
    {"walk", SCRIPT_WALK, 3, "walk DX DZ SECONDS"},
    {"wait", SCRIPT_WAIT, 1, "wait MS"},
    {"ping", SCRIPT_PING, 0, "ping"},
    {"quit", SCRIPT_QUIT, 0, "quit"},
};

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

int script_parse_line(const char *line, script_cmd *cmd, char *err, size_t errlen)
{
    char buf[SCRIPT_LINE_MAX + 1];
    size_t n = strlen(line);
    if (n > SCRIPT_LINE_MAX) {
        snprintf(err, errlen, "line longer than %d bytes", SCRIPT_LINE_MAX);
        return -1;
    }
    memcpy(buf, line, n + 1);
    char *hash = strchr(buf, '#');
    if (hash)
        *hash = '\0';

    char *tok[5], *save = NULL;
    int nt = 0;
    for (char *t = strtok_r(buf, " \t\r\v\f", &save); t; t = strtok_r(NULL, " \t\r\v\f", &save)) {
        if (nt == 5) {
            snprintf(err, errlen, "too many words");
            return -1;
        }
        tok[nt++] = t;
    }
    if (nt == 0)
        return 0;

    size_t k = 0;
    while (k < sizeof commands / sizeof commands[0] && strcmp(commands[k].name, tok[0]) != 0)
        k++;
    if (k == sizeof commands / sizeof commands[0]) {
        snprintf(err, errlen, "unknown command '%.40s' (move, walk, wait, ping, quit)", tok[0]);
        return -1;
    }
    if (nt - 1 != commands[k].nargs) {
        snprintf(err, errlen, "%s: expected %d argument%s: %s", commands[k].name, commands[k].nargs,
                 commands[k].nargs == 1 ? "" : "s", commands[k].usage);
        return -1;
    }
    cmd->op = commands[k].op;
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

/* ---- the runner -------------------------------------------------------- */

struct script {
    ev_loop *loop;
    conn_ctx *ctx;
    conn *c;
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

    int keepalive_timer;
    int linger_timer;
};

static void advance(script *s);

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
    for (size_t k = 0; k < sizeof commands / sizeof commands[0]; k++)
        if (commands[k].op == op)
            return commands[k].name;
    return "?";
}

/* Ends the running command; move, walk and wait report where we are. */
static void cmd_done(script *s)
{
    conn_timer_stop(s->loop, &s->cmd_timer);
    s->running = 0;
    if (s->cur.op == SCRIPT_MOVE || s->cur.op == SCRIPT_WALK || s->cur.op == SCRIPT_WAIT)
        events_done(op_name(s->cur.op), conn_get_view(s->c)->pos);
}

static void cmd_finish(script *s)
{
    cmd_done(s);
    advance(s);
}

static void on_linger(ev_loop *loop, void *data)
{
    script *s = data;
    (void)loop;
    s->linger_timer = -1;
    conn_close(s->c);
}

/* Says bye and gives the server QUIT_LINGER_NS to close; abandons any
 * running command. */
static void quit(script *s)
{
    if (s->quitting)
        return;
    s->quitting = 1;
    conn_timer_stop(s->loop, &s->cmd_timer);
    s->running = 0;
    if (conn_bye(s->c, PROTO_BYE_QUIT))
        events_bye_sent(PROTO_BYE_QUIT);
    s->linger_timer = conn_timer_start(s->loop, QUIT_LINGER_NS, 0, on_linger, s);
}

/* One step of a move: the next point on the straight line from the last
 * point sent, max_speed / rate further, never past the target. Stepping
 * from what we sent rather than from the authoritative position keeps the
 * requests ahead of the server by the round trip instead of dragging it
 * back; once the target is reached it is sent again until the server
 * arrives or gives up. */
static void move_step(script *s)
{
    double step = conn_get_view(s->c)->welcome.max_speed / s->rate;
    double d = dist3(s->target, s->base);
    float next[3];
    for (int i = 0; i < 3; i++)
        next[i] = d <= step ? s->target[i] : (float)(s->base[i] + (s->target[i] - s->base[i]) * (step / d));
    if (conn_send_move(s->c, next))
        memcpy(s->base, next, sizeof next);
}

/* True when the move is over: arrived, stalled or out of time. */
static int move_over(script *s, uint64_t now)
{
    double d = dist3(conn_get_view(s->c)->pos, s->target);
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
    uint32_t seq = conn_send_move(s->c, next);
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
           (conn_get_view(s->c)->ack >= s->walk_seq || now - s->t_sent >= WALK_ACK_WAIT_NS);
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
    const conn_view *v = conn_get_view(s->c);
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
        s->cmd_timer = conn_timer_start(s->loop, s->period_ns, s->period_ns, on_cmd_timer, s);
        break;
    case SCRIPT_WALK: {
        double n = round(cmd->arg[2] * s->rate);
        memcpy(s->from, v->pos, sizeof s->from);
        s->walk_k = 0;
        s->walk_n = n < 1.0 ? 1u : (unsigned)n;
        walk_step(s, now);
        s->cmd_timer = conn_timer_start(s->loop, s->period_ns, s->period_ns, on_cmd_timer, s);
        break;
    }
    case SCRIPT_WAIT:
        s->cmd_timer = conn_timer_start(s->loop, (uint64_t)(cmd->arg[0] * (double)NS_PER_MS), 0, on_cmd_timer, s);
        break;
    case SCRIPT_PING:
        s->ping_stamp = ev_clock(s->loop) / 1000u;
        if (conn_send_ping(s->c, s->ping_stamp) < 0) {
            log_warn("ping not sent: output backlog full");
            cmd_done(s);
            return;
        }
        s->cmd_timer = conn_timer_start(s->loop, PING_WAIT_NS, 0, on_cmd_timer, s);
        break;
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
    while (!s->running && !s->quitting && conn_state(s->c) == CONN_JOINED) {
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

static void on_msg(conn *c, const proto_msg *m, void *data)
{
    script *s = data;
    const conn_view *v = conn_get_view(c);
    uint64_t now = ev_clock(s->loop);
    events_message(m, now / 1000u);
    switch (m->type) {
    case PROTO_JOIN_OK:
        advance(s);
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
    default:
        break;
    }
}

static void on_close(conn *c, const conn_end *end, void *data)
{
    script *s = data;
    (void)c;
    if (events_conn_end(-1, end, conn_ctx_peer(s->ctx)))
        fail(s, 1);
    events_closed(-1);
    if (!s->quitting)
        fail(s, 1);
    conn_timer_stop(s->loop, &s->cmd_timer);
    conn_timer_stop(s->loop, &s->linger_timer);
    ev_stop(s->loop);
}

static const conn_handler handler = {on_msg, on_close};

static void on_keepalive(ev_loop *loop, void *data)
{
    script *s = data;
    (void)loop;
    conn_keepalive(s->c);
}

/* ---- input ------------------------------------------------------------- */

static void push(script *s, const script_cmd *cmd)
{
    if (s->q_len == s->q_cap) {
        s->q_cap = s->q_cap ? s->q_cap * 2 : 16;
        s->q = xrealloc(s->q, s->q_cap * sizeof *s->q);
    }
    s->q[s->q_len++] = *cmd;
}

/* Parses one line and queues its command. Returns 0, or -1 after printing
 * the error (naming the line) on stderr. */
static int take_line(script *s, const char *line)
{
    script_cmd cmd;
    char err[256];
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
    script *s = xcalloc(1, sizeof *s);
    s->loop = loop;
    s->rate = o->rate;
    s->period_ns = (uint64_t)((double)NS_PER_S / o->rate);
    s->cmd_timer = s->keepalive_timer = s->linger_timer = -1;
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
    s->ctx = conn_ctx_create(loop, o->net.host, o->net.port, err, sizeof err);
    if (!s->ctx) {
        fprintf(stderr, "cvre-client: %s\n", err);
        *exit_code = 1;
        script_free(s);
        return NULL;
    }
    s->c = conn_open(s->ctx, o->net.name, o->net.box, &handler, s);
    s->keepalive_timer = conn_timer_start(s->loop, KEEPALIVE_CHECK_NS, KEEPALIVE_CHECK_NS, on_keepalive, s);
    prompt(s);
    return s;
}

void script_interrupt(script *s)
{
    input_over(s);
    if (s->quitting)
        conn_close(s->c);
    else
        quit(s);
}

int script_exit_code(const script *s) { return s->exit_code; }

void script_free(script *s)
{
    if (!s)
        return;
    input_over(s);
    conn_timer_stop(s->loop, &s->cmd_timer);
    conn_timer_stop(s->loop, &s->keepalive_timer);
    conn_timer_stop(s->loop, &s->linger_timer);
    conn_free(s->c);
    conn_ctx_free(s->ctx);
    free(s->q);
    free(s);
}
