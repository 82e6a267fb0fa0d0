/*
 * main.c: cvre-client, the thin client. Parses the flags, picks the mode
 * (bot swarm, script, interactive) and runs it on one event loop, which also
 * receives SIGINT and SIGTERM through a signalfd so that a signal ends the
 * session with a bye rather than killing it mid-frame.
 */
#include <ctype.h>
#include <errno.h>
#include <math.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>
#include <sys/signalfd.h>
#include <termios.h>
#include <unistd.h>

#include "avatar.h"
#include "bots.h"
#include "ev.h"
#include "log.h"
#include "num.h"
#include "proto.h"
#include "script.h"

/* Flag bounds. A move per millisecond is the bot scheduler's resolution,
 * and a move per 100 s keeps the period in range of a u64 of nanoseconds
 * even when multiplied by the bot count; a million bots is far past what
 * one process's descriptors allow anyway. */
#define RATE_MIN 0.01
#define RATE_MAX 1000.0
#define BOTS_MAX 1000000u
#define DURATION_MAX 86400.0
#define RAMP_MAX 1e6
/* Descriptors besides the bots' sockets: stdio, the signalfd, epoll. */
#define SPARE_FDS 64
/* --ws's port when none is given: tools/demo.sh's --web. */
#define WS_PORT_DEFAULT 8080

typedef struct options {
    session_params net;
    int name_given;
    int port_given;
    double rate;
    const char *script;
    unsigned bots;
    int pattern;
    double duration;
    double ramp;
    int no_handshake;
    int pose;  /* bots: facing and head with every move */
    int login; /* ask for the password on the terminal if CVRE_PASSWORD is unset */
    int json;  /* JSON lines even on a terminal */
} options;

static void usage(FILE *f)
{
    fputs("usage: cvre-client [--host H] [--port P] [--ws] [--name NAME] [--login] [--box X,Y,Z]\n"
          "                   [--rate HZ] [--script FILE] [--json]\n"
          "       cvre-client --bots N [--pattern random-walk|circle] [--duration S] [--ramp N]\n"
          "                   [--no-handshake] [--pose] [--host H] [--port P] [--ws] [--name PREFIX]\n"
          "                   [--rate HZ]\n"
          "       cvre-client --help | --version\n"
          "\n"
          "The thin client of a cvre-server: one user driven by hand or by a script, or a\n"
          "swarm of bots for load tests, on one event loop. Every event it receives is\n"
          "printed on stdout as one JSON object per line; messages go to stderr. Typing\n"
          "at a terminal (standard input and output both one), a person gets short lines\n"
          "instead: joins, leaves, objects, errors, command results, a collision once per\n"
          "contact, no snapshots.\n"
          "\n"
          "Options:\n"
          "  --host H           server address (default 127.0.0.1; IPv4, IPv6 or a name)\n"
          "  --port P           server port (default 7878, or 8080 with --ws)\n"
          "  --ws               over a WebSocket to the server's --web port instead of raw\n"
          "                     TCP (the same frames, one per binary message)\n"
          "  --name NAME        display name (default user); for bots the prefix of <NAME>-<i>\n"
          "  --login            join as the account --name; the password comes from\n"
          "                     CVRE_PASSWORD, else it is asked for on the terminal\n"
          "  --box X,Y,Z        avatar box size in metres (default 0.6,1.8,0.6)\n"
          "  --rate HZ          moves per second while walking (default 20)\n"
          "  --script FILE      run the commands in FILE instead of standard input\n"
          "  --json             JSON lines, every event, even at a terminal\n"
          "  --bots N           run N bots (guests) instead of one user\n"
          "  --pattern P        bots: random-walk (default) or circle\n"
          "  --duration S       bots: seconds to run (default 10)\n"
          "  --ramp N           bots: connections started per second (default 1000)\n"
          "  --no-handshake     bots: skip hello and join, send only moves\n"
          "  --pose             bots: every move carries a facing (the way they walk) and a\n"
          "                     head pose, as a VR client's would\n"
          "  --help             show this help\n"
          "  --version          show the version\n"
          "\n"
          "Commands (standard input, interactively on a terminal, or --script FILE):\n"
          "  move X Y Z, walk DX DZ SECONDS, wait MS, ping, quit;\n"
          "  pose YAW PITCH (degrees about +y, and up: moves carry it from then on);\n"
          "  import FILE [--up y|z] [--scale UNITS] [--name NAME] at X Y Z\n"
          "  [--anchor origin|base] [--drop] [--yaw DEGREES] [--size S],\n"
          "  place ID X Y Z [--yaw DEGREES] [--size S], remove ID (accounts only);\n"
          "  fetch ID FILE.obj|FILE.glb (the mesh of an object in view, as OBJ or glTF).\n"
          "  import's at X Y Z places the model's origin; --anchor base places the bottom\n"
          "  centre of its box there instead, and --drop then lowers or raises the box\n"
          "  onto the highest surface under it the client knows of (else the floor).\n"
          "\n"
          "Environment:\n"
          "  CVRE_TOKEN         join with this resume token (the hex resume_token of an\n"
          "                     earlier join_ok event; used once)\n"
          "  CVRE_PASSWORD      join as the account --name with this password\n"
          "Without either, or --login, a user joins as a guest (walk and look only).\n"
          "\n"
          "Exit status:\n"
          "  0  normal end (bots: no error and no disconnect), even if an object command\n"
          "     was refused\n"
          "  1  the connection failed, the server sent an error or closed first (bots:\n"
          "     any error or disconnect)\n"
          "  2  bad flags, a bad script line, or no password to be had\n"
          "\n"
          "See client/README.md for the events and the bots' summary.\n",
          f);
}

/* Reports a bad flag value; returns -EINVAL for parse_args to pass on. */
static int bad(const char *flag, const char *value, const char *want)
{
    fprintf(stderr, "cvre-client: %s: bad value '%s': %s (see --help)\n", flag, value, want);
    return -EINVAL;
}

/* The flag value parsers: 0, or -EINVAL when s is not a value in range. */
static int parse_double(const char *s, double lo, double hi, int lo_open, double *out)
{
    double v;
    if (num_parse_real(s, lo, hi, &v) < 0 || (lo_open && v == lo))
        return -EINVAL;
    *out = v;
    return 0;
}

static int parse_unsigned(const char *s, unsigned long lo, unsigned long hi, unsigned long *out)
{
    long long v;
    if (num_parse_int(s, (long long)lo, (long long)hi, &v) < 0)
        return -EINVAL;
    *out = (unsigned long)v;
    return 0;
}

static int parse_box(const char *s, float box[3])
{
    const char *p = s;
    for (int i = 0; i < 3; i++) {
        char *end;
        double v = strtod(p, &end);
        if (end == p || !isfinite(v) || v < PROTO_BOX_MIN || v > PROTO_BOX_MAX)
            return -EINVAL;
        if (*end != (i < 2 ? ',' : '\0'))
            return -EINVAL;
        box[i] = (float)v;
        p = end + 1;
    }
    return 0;
}

/* Names travel as UTF-8 without control characters; catching the length
 * and control characters here gives a better message than the server's
 * refusal. */
static int name_ok(const char *name, size_t max)
{
    size_t n = strlen(name);
    if (n == 0 || n > max)
        return 0;
    for (size_t i = 0; i < n; i++)
        if ((unsigned char)name[i] < 0x20u || name[i] == 0x7f)
            return 0;
    return 1;
}

static unsigned digits(unsigned v)
{
    unsigned d = 1;
    while (v >= 10) {
        v /= 10;
        d++;
    }
    return d;
}

/* Fills *o from argv. Returns 0 to go on, -ECANCELED after --help or
 * --version (printed), -EINVAL after a usage error (reported). */
static int parse_args(int argc, char **argv, options *o)
{
    *o = (options){.net = {.host = "127.0.0.1", .port = 7878, .name = "user", .box = {AVATAR_WIDTH, AVATAR_HEIGHT, AVATAR_WIDTH}},
                   .rate = 20.0, .pattern = BOTS_RANDOM_WALK, .duration = 10.0, .ramp = 1000.0};
    for (int i = 1; i < argc; i++) {
        const char *arg = argv[i];
        if (strncmp(arg, "--", 2) != 0) {
            fprintf(stderr, "cvre-client: unexpected argument '%s' (see --help)\n", arg);
            return -EINVAL;
        }
        if (strcmp(arg, "--help") == 0) {
            usage(stdout);
            return -ECANCELED;
        }
        if (strcmp(arg, "--version") == 0) {
            printf("cvre-client %s\n", CVRE_VERSION);
            return -ECANCELED;
        }
        if (strcmp(arg, "--no-handshake") == 0) {
            o->no_handshake = 1;
            continue;
        }
        if (strcmp(arg, "--pose") == 0) {
            o->pose = 1;
            continue;
        }
        if (strcmp(arg, "--login") == 0) {
            o->login = 1;
            continue;
        }
        if (strcmp(arg, "--json") == 0) {
            o->json = 1;
            continue;
        }
        if (strcmp(arg, "--ws") == 0) {
            o->net.ws = 1;
            continue;
        }
        /* Every other flag takes a value: --flag VALUE or --flag=VALUE. */
        char flag[32];
        const char *eq = strchr(arg, '='), *val;
        size_t flen = eq ? (size_t)(eq - arg) : strlen(arg);
        if (flen >= sizeof flag) {
            fprintf(stderr, "cvre-client: unknown flag '%s' (see --help)\n", arg);
            return -EINVAL;
        }
        memcpy(flag, arg, flen);
        flag[flen] = '\0';
        static const char *const known[] = {"--host", "--port", "--name", "--box", "--rate", "--script",
                                            "--bots", "--pattern", "--duration", "--ramp"};
        size_t k = 0;
        while (k < sizeof known / sizeof known[0] && strcmp(known[k], flag) != 0)
            k++;
        if (k == sizeof known / sizeof known[0]) {
            fprintf(stderr, "cvre-client: unknown flag '%s' (see --help)\n", flag);
            return -EINVAL;
        }
        if (eq) {
            val = eq + 1;
        } else if (i + 1 < argc) {
            val = argv[++i];
        } else {
            fprintf(stderr, "cvre-client: %s needs a value (see --help)\n", flag);
            return -EINVAL;
        }

        unsigned long u;
        if (strcmp(flag, "--host") == 0) {
            if (!*val)
                return bad(flag, val, "an address or host name");
            o->net.host = val;
        } else if (strcmp(flag, "--port") == 0) {
            if (parse_unsigned(val, 1, 65535, &u) < 0)
                return bad(flag, val, "a port number 1..65535");
            o->net.port = (uint16_t)u;
            o->port_given = 1;
        } else if (strcmp(flag, "--name") == 0) {
            if (!name_ok(val, PROTO_NAME_MAX))
                return bad(flag, val, "1 to 32 bytes, no control characters");
            o->net.name = val;
            o->name_given = 1;
        } else if (strcmp(flag, "--box") == 0) {
            if (parse_box(val, o->net.box) < 0)
                return bad(flag, val, "X,Y,Z with each edge in [0.1, 4] metres");
        } else if (strcmp(flag, "--rate") == 0) {
            if (parse_double(val, RATE_MIN, RATE_MAX, 0, &o->rate) < 0)
                return bad(flag, val, "moves per second, 0.01 to 1000");
        } else if (strcmp(flag, "--script") == 0) {
            o->script = val;
        } else if (strcmp(flag, "--bots") == 0) {
            if (parse_unsigned(val, 1, BOTS_MAX, &u) < 0)
                return bad(flag, val, "a count from 1 to 1000000");
            o->bots = (unsigned)u;
        } else if (strcmp(flag, "--pattern") == 0) {
            if (strcmp(val, "random-walk") == 0)
                o->pattern = BOTS_RANDOM_WALK;
            else if (strcmp(val, "circle") == 0)
                o->pattern = BOTS_CIRCLE;
            else
                return bad(flag, val, "random-walk or circle");
        } else if (strcmp(flag, "--duration") == 0) {
            if (parse_double(val, 0.0, DURATION_MAX, 1, &o->duration) < 0)
                return bad(flag, val, "seconds, more than 0 and at most 86400");
        } else {
            if (parse_double(val, 0.0, RAMP_MAX, 1, &o->ramp) < 0)
                return bad(flag, val, "connections per second, more than 0 and at most 1000000");
        }
    }
    if (o->net.ws && !o->port_given)
        o->net.port = WS_PORT_DEFAULT;
    if (o->login && o->bots) {
        fprintf(stderr, "cvre-client: --login is for one user, not --bots (bots are guests)\n");
        return -EINVAL;
    }
    if (o->no_handshake && o->bots == 0) {
        fprintf(stderr, "cvre-client: --no-handshake needs --bots\n");
        return -EINVAL;
    }
    if (o->pose && (o->bots == 0 || o->no_handshake)) {
        fprintf(stderr, "cvre-client: --pose needs --bots that join (a script has the pose command)\n");
        return -EINVAL;
    }
    if (o->bots > 0) {
        if (!o->name_given)
            o->net.name = "bot";
        if (strlen(o->net.name) + 1 + digits(o->bots - 1) > PROTO_NAME_MAX) {
            fprintf(stderr, "cvre-client: --name: '%s-%u' would be longer than %u bytes\n",
                    o->net.name, o->bots - 1, PROTO_NAME_MAX);
            return -EINVAL;
        }
    }
    return 0;
}

/* Lifts the descriptor limit to the hard limit, since every bot is a
 * socket. Returns how many fds the loop should be able to watch. */
static int raise_nofile(unsigned nbots)
{
    unsigned long want = (unsigned long)nbots + SPARE_FDS;
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) < 0)
        return (int)want;
    if (rl.rlim_cur < rl.rlim_max) {
        rl.rlim_cur = rl.rlim_max;
        if (setrlimit(RLIMIT_NOFILE, &rl) < 0)
            getrlimit(RLIMIT_NOFILE, &rl);
    }
    if (rl.rlim_cur != RLIM_INFINITY && rl.rlim_cur < want) {
        log_warn("only %lu file descriptors allowed: some of the %u bots will fail to connect",
                 (unsigned long)rl.rlim_cur, nbots);
        want = (unsigned long)rl.rlim_cur;
    }
    return (int)want;
}

/* The running mode; exactly one of the two is set. */
typedef struct mode {
    script *script;
    bots *bots;
} mode;

static void on_signal(ev_loop *loop, int fd, unsigned events, void *data)
{
    mode *m = data;
    struct signalfd_siginfo si;
    (void)loop;
    (void)events;
    while (read(fd, &si, sizeof si) == (ssize_t)sizeof si) {
        if (m->bots)
            bots_interrupt(m->bots);
        else
            script_interrupt(m->script);
    }
}

/* A password of 1..PROTO_PASSWORD_MAX bytes into cred. 0, or -EINVAL with a
 * message (never the password). */
static int set_password(session_credential *cred, const char *pw)
{
    size_t n = strlen(pw);

    if (n < 1 || n > PROTO_PASSWORD_MAX) {
        fprintf(stderr, "cvre-client: a password is 1 to %u bytes\n", PROTO_PASSWORD_MAX);
        return -EINVAL;
    }
    cred->kind = PROTO_CRED_PASSWORD;
    cred->len = (uint32_t)n;
    memcpy(cred->secret, pw, n);
    return 0;
}

/* Asks for the password of name on the terminal, without echo. 0, or
 * -EINVAL with a message. */
static int ask_password(const char *name, session_credential *cred)
{
    char line[PROTO_PASSWORD_MAX + 2];
    struct termios old, quiet;
    FILE *tty = fopen("/dev/tty", "r+");
    int fd, echo_off, rc;
    char *got;

    if (!tty) {
        fprintf(stderr, "cvre-client: --login: no terminal to ask for the password; set CVRE_PASSWORD\n");
        return -EINVAL;
    }
    fd = fileno(tty);
    fprintf(tty, "password for %s: ", name);
    fflush(tty);
    echo_off = tcgetattr(fd, &old) == 0;
    if (echo_off) {
        quiet = old;
        quiet.c_lflag &= ~(tcflag_t)ECHO;
        tcsetattr(fd, TCSAFLUSH, &quiet);
    }
    got = fgets(line, sizeof line, tty);
    if (echo_off)
        tcsetattr(fd, TCSAFLUSH, &old);
    fputc('\n', tty);
    fclose(tty);
    if (!got) {
        fprintf(stderr, "cvre-client: --login: no password given\n");
        return -EINVAL;
    }
    line[strcspn(line, "\r\n")] = 0;
    rc = set_password(cred, line);
    memset(line, 0, sizeof line);
    return rc;
}

/* What the join carries: a resume token (CVRE_TOKEN), a password
 * (CVRE_PASSWORD, or asked for with --login), or nothing (a guest).
 * 0, or -EINVAL with a message. */
static int login_credential(const options *o, session_credential *cred)
{
    const char *token = getenv("CVRE_TOKEN"), *pw = getenv("CVRE_PASSWORD");

    memset(cred, 0, sizeof *cred);
    if (token && *token) {
        int ok = strlen(token) == 2 * PROTO_RESUME_TOKEN_SIZE;
        for (unsigned i = 0; ok && i < PROTO_RESUME_TOKEN_SIZE; i++) {
            unsigned v;
            ok = sscanf(token + 2 * i, "%2x", &v) == 1 && isxdigit((unsigned char)token[2 * i]) &&
                 isxdigit((unsigned char)token[2 * i + 1]);
            cred->secret[i] = (uint8_t)v;
        }
        if (!ok) {
            fprintf(stderr, "cvre-client: CVRE_TOKEN must be the %u hex digits of a resume_token\n",
                    2 * PROTO_RESUME_TOKEN_SIZE);
            return -EINVAL;
        }
        cred->kind = PROTO_CRED_TOKEN;
        cred->len = PROTO_RESUME_TOKEN_SIZE;
        return 0;
    }
    if (pw && *pw)
        return set_password(cred, pw);
    return o->login ? ask_password(o->net.name, cred) : 0;
}

int main(int argc, char **argv)
{
    options o;
    int code = parse_args(argc, argv, &o);
    if (code < 0)
        return code == -ECANCELED ? 0 : 2; /* --help or --version; a usage error */

    signal(SIGPIPE, SIG_IGN);
    int max_fd = o.bots ? raise_nofile(o.bots) : SPARE_FDS;

    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    sigprocmask(SIG_BLOCK, &set, NULL);
    int sfd = signalfd(-1, &set, SFD_NONBLOCK | SFD_CLOEXEC);
    ev_loop *loop = ev_create(max_fd);
    if (sfd < 0 || !loop) {
        log_error("cannot set up the event loop: %s", strerror(errno));
        return 1;
    }

    mode m = {0};
    code = 1;
    if (o.bots) {
        bots_opts bo = {.net = o.net, .rate = o.rate, .count = o.bots, .pattern = o.pattern,
                        .duration = o.duration, .ramp = o.ramp, .no_handshake = o.no_handshake,
                        .pose = o.pose};
        m.bots = bots_create(loop, &bo, &code);
    } else {
        script_opts so = {.net = o.net, .rate = o.rate, .file = o.script, .json = o.json};
        if (login_credential(&o, &so.login) < 0)
            code = 2;
        else
            m.script = script_create(loop, &so, &code);
        memset(&so.login, 0, sizeof so.login);
    }
    if (m.bots || m.script) {
        int rc = ev_io_add(loop, sfd, EV_READ, on_signal, &m);
        if (rc == 0)
            rc = ev_run(loop);
        if (rc < 0) {
            log_error("event loop: %s", strerror(-rc));
            code = 1;
        } else {
            code = m.bots ? bots_exit_code(m.bots) : script_exit_code(m.script);
        }
        bots_free(m.bots);
        script_free(m.script);
        ev_io_del(loop, sfd);
    }
    close(sfd);
    ev_destroy(loop);
    return code;
}
