/*
 * script_parse.c: the client's command language (see script.h): a line
 * split into words, each command's arguments checked against its bounds.
 * Nothing here touches the network; script.c runs what this accepts.
 */
#include "script.h"

#include <errno.h>
#include <inttypes.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "err.h"
#include "num.h"
#include "utf8.h"

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
/* pose: straight down to straight up. */
#define PITCH_MAX_DEG 90.0

/* Words on one line: a full import has 19. */
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
    {"pose", SCRIPT_POSE, 2, "pose YAW PITCH"},
    {"import", SCRIPT_IMPORT, -1,
     "import FILE [--up y|z] [--scale UNITS] [--name NAME] at X Y Z [--anchor origin|base] [--drop] "
     "[--yaw DEGREES] [--size S]"},
    {"place", SCRIPT_PLACE, -1, "place ID X Y Z [--yaw DEGREES] [--size S]"},
    {"remove", SCRIPT_REMOVE, -1, "remove ID"},
    {"fetch", SCRIPT_FETCH, -1, "fetch ID FILE.obj|FILE.glb"},
    {"quit", SCRIPT_QUIT, 0, "quit"},
};
#define NCOMMANDS (sizeof commands / sizeof commands[0])

const char *script_op_name(int op)
{
    for (size_t k = 0; k < NCOMMANDS; k++)
        if (commands[k].op == op)
            return commands[k].name;
    return "?";
}

/* An object id: decimal digits only, 1..2^32-1 (0 means "none" on the
 * wire). Returns 0 or -EINVAL. */
static int parse_id(const char *tok, uint32_t *out)
{
    long long v;
    if (num_parse_int(tok, 1, UINT32_MAX, &v) < 0)
        return -EINVAL;
    *out = (uint32_t)v;
    return 0;
}

static int is_blank(char ch) { return ch == ' ' || ch == '\t' || ch == '\r' || ch == '\v' || ch == '\f'; }

/*
 * Splits buf in place into words (at most WORDS_MAX) at blanks. A word that
 * starts with a double quote runs to the next one and may hold blanks and
 * '#' (there is no escape: a path with a quote in it cannot be written); an
 * unquoted '#' ends the line. Returns the count, or -EINVAL with a message.
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
        if (n == WORDS_MAX)
            return cvre_fail(err, errlen, -EINVAL, "too many words");
        if (*p == '"') {
            char *close = strchr(p + 1, '"');
            if (!close)
                return cvre_fail(err, errlen, -EINVAL, "unterminated quote");
            *close = '\0';
            word[n++] = p + 1;
            p = close + 1;
            if (*p != '\0' && *p != '#' && !is_blank(*p))
                return cvre_fail(err, errlen, -EINVAL, "a blank must follow a closing quote");
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

/* The options of import and place; place takes those from OPT_YAW on. */
enum { OPT_AT, OPT_UP, OPT_SCALE, OPT_NAME, OPT_ANCHOR, OPT_DROP, OPT_YAW, OPT_SIZE, OPT_COUNT };
static const char *const opt_names[OPT_COUNT] = {"at", "--up", "--scale", "--name", "--anchor", "--drop",
                                                 "--yaw", "--size"};

/* How many words follow an option's name. */
static int opt_values(int o) { return o == OPT_AT ? 3 : o == OPT_DROP ? 0 : 1; }

/*
 * Parses the words of an import after FILE, or of a place after ID X Y Z:
 * the options in any order, each at most once ("at X Y Z" counts as one,
 * and only import takes it and the file and anchoring options). Returns 0,
 * or -EINVAL with a message that ends with the usage.
 */
static int parse_object_opts(char **w, int n, const char *usage, script_cmd *cmd, char *err, size_t errlen)
{
    const char *what = cmd->op == SCRIPT_IMPORT ? "import" : "place";
    unsigned seen = 0;
    for (int i = 0; i < n;) {
        int o = 0;
        while (o < OPT_COUNT && strcmp(opt_names[o], w[i]) != 0)
            o++;
        if (o == OPT_COUNT || (cmd->op == SCRIPT_PLACE && o < OPT_YAW))
            return cvre_fail(err, errlen, -EINVAL, "%s: unexpected '%.40s': %s", what, w[i], usage);
        if (seen & 1u << o)
            return cvre_fail(err, errlen, -EINVAL, "%s: '%s' given twice: %s", what, opt_names[o], usage);
        seen |= 1u << o;
        int nv = opt_values(o);
        if (n - i - 1 < nv)
            return cvre_fail(err, errlen, -EINVAL, "%s: '%s' needs %s: %s", what, opt_names[o],
                             o == OPT_AT ? "X Y Z" : "a value", usage);
        const char *v = nv ? w[i + 1] : "";
        double lo = OBJ_SCALE_MIN, hi = OBJ_SCALE_MAX;
        int ok = 1;
        switch (o) {
        case OPT_AT:
            lo = -COORD_MAX;
            hi = COORD_MAX;
            for (int k = 0; k < 3 && ok; k++) {
                v = w[i + 1 + k];
                ok = num_parse_real(v, lo, hi, &cmd->arg[k]) == 0;
            }
            break;
        case OPT_UP:
            if (strcmp(v, "y") == 0 || strcmp(v, "Y") == 0)
                cmd->up_axis = PROTO_UP_Y;
            else if (strcmp(v, "z") == 0 || strcmp(v, "Z") == 0)
                cmd->up_axis = PROTO_UP_Z;
            else
                return cvre_fail(err, errlen, -EINVAL, "import: --up: bad axis '%.40s' (want y or z): %s", v, usage);
            break;
        case OPT_NAME:
            if (!object_name_ok(v))
                return cvre_fail(err, errlen, -EINVAL,
                                 "import: --name: bad name '%.40s' (want 1 to %u bytes of UTF-8, no control "
                                 "characters): %s",
                                 v, PROTO_OBJECT_NAME_MAX, usage);
            snprintf(cmd->name, sizeof cmd->name, "%s", v);
            break;
        case OPT_ANCHOR:
            if (strcmp(v, "origin") == 0)
                cmd->anchor = SCRIPT_ANCHOR_ORIGIN;
            else if (strcmp(v, "base") == 0)
                cmd->anchor = SCRIPT_ANCHOR_BASE;
            else
                return cvre_fail(err, errlen, -EINVAL, "import: --anchor: bad anchor '%.40s' (want origin or base): %s",
                                 v, usage);
            break;
        case OPT_DROP:
            cmd->drop = 1;
            break;
        case OPT_YAW:
            lo = -YAW_MAX_DEG;
            hi = YAW_MAX_DEG;
            ok = num_parse_real(v, lo, hi, &cmd->yaw_deg) == 0;
            cmd->has_yaw = 1;
            break;
        case OPT_SCALE:
            ok = num_parse_real(v, lo, hi, &cmd->unit_scale) == 0;
            break;
        default: /* OPT_SIZE */
            ok = num_parse_real(v, lo, hi, &cmd->size) == 0;
            cmd->has_size = 1;
            break;
        }
        if (!ok)
            return cvre_fail(err, errlen, -EINVAL, "%s: %s: bad number '%.40s' (want a finite number in [%g, %g]): %s",
                             what, opt_names[o], v, lo, hi, usage);
        i += 1 + nv;
    }
    if (cmd->op == SCRIPT_IMPORT && !(seen & 1u << OPT_AT))
        return cvre_fail(err, errlen, -EINVAL, "import: missing 'at X Y Z': %s", usage);
    return 0;
}

/* import, place, remove and fetch; w[0] is the command. Returns 0 or -EINVAL. */
static int parse_object_cmd(char **w, int n, const char *usage, script_cmd *cmd, char *err, size_t errlen)
{
    cmd->yaw_deg = 0.0;
    cmd->size = 1.0;
    cmd->unit_scale = 1.0;
    cmd->up_axis = PROTO_UP_Y;
    cmd->anchor = SCRIPT_ANCHOR_ORIGIN;
    if (cmd->op == SCRIPT_IMPORT) {
        if (n < 2 || w[1][0] == '\0')
            return cvre_fail(err, errlen, -EINVAL, "import: expected a file: %s", usage);
        int rc = parse_object_opts(w + 2, n - 2, usage, cmd, err, errlen);
        if (rc < 0)
            return rc;
        cmd->file = cvre_xstrdup(w[1]);
        return 0;
    }
    if (cmd->op == SCRIPT_FETCH) {
        const char *dot = n == 3 ? strrchr(w[2], '.') : NULL;
        if (n != 3 || parse_id(w[1], &cmd->object_id) < 0 || !dot || (strcmp(dot, ".obj") && strcmp(dot, ".glb")))
            return cvre_fail(err, errlen, -EINVAL, "fetch: expected an object id and a file ending in .obj or .glb: %s",
                             usage);
        cmd->file = cvre_xstrdup(w[2]);
        return 0;
    }
    const char *what = cmd->op == SCRIPT_PLACE ? "place" : "remove";
    int fixed = cmd->op == SCRIPT_PLACE ? 5 : 2;
    if (n < fixed || (cmd->op == SCRIPT_REMOVE && n > fixed))
        return cvre_fail(err, errlen, -EINVAL, "%s: expected %s: %s", what,
                         cmd->op == SCRIPT_PLACE ? "ID X Y Z" : "ID", usage);
    if (parse_id(w[1], &cmd->object_id) < 0)
        return cvre_fail(err, errlen, -EINVAL, "%s: bad object id '%.40s' (want 1 to %" PRIu32 "): %s", what, w[1],
                         UINT32_MAX, usage);
    if (cmd->op == SCRIPT_REMOVE)
        return 0;
    for (int k = 0; k < 3; k++)
        if (num_parse_real(w[2 + k], -COORD_MAX, COORD_MAX, &cmd->arg[k]) < 0)
            return cvre_fail(err, errlen, -EINVAL, "place: bad number '%.40s' (want a finite number in [%g, %g]): %s",
                             w[2 + k], -COORD_MAX, COORD_MAX, usage);
    return parse_object_opts(w + 5, n - 5, usage, cmd, err, errlen);
}

int script_parse_line(const char *line, script_cmd *cmd, char *err, size_t errlen)
{
    char buf[SCRIPT_LINE_MAX + 1];
    size_t n = strlen(line);
    if (n > SCRIPT_LINE_MAX)
        return cvre_fail(err, errlen, -EINVAL, "line longer than %d bytes", SCRIPT_LINE_MAX);
    memcpy(buf, line, n + 1);

    char *tok[WORDS_MAX];
    int nt = split_words(buf, tok, err, errlen);
    if (nt <= 0)
        return nt;

    size_t k = 0;
    while (k < NCOMMANDS && strcmp(commands[k].name, tok[0]) != 0)
        k++;
    if (k == NCOMMANDS)
        return cvre_fail(err, errlen, -EINVAL,
                         "unknown command '%.40s' (move, walk, wait, ping, pose, import, place, remove, fetch, quit)", tok[0]);
    *cmd = (script_cmd){.op = commands[k].op};
    if (commands[k].nargs < 0) {
        int rc = parse_object_cmd(tok, nt, commands[k].usage, cmd, err, errlen);
        return rc < 0 ? rc : 1;
    }
    if (nt - 1 != commands[k].nargs)
        return cvre_fail(err, errlen, -EINVAL, "%s: expected %d argument%s: %s", commands[k].name, commands[k].nargs,
                         commands[k].nargs == 1 ? "" : "s", commands[k].usage);
    for (int i = 0; i < commands[k].nargs; i++) {
        double lo = -COORD_MAX, hi = COORD_MAX;
        if (cmd->op == SCRIPT_WAIT) {
            lo = 0.0;
            hi = WAIT_MAX_MS;
        } else if (cmd->op == SCRIPT_WALK && i == 2) {
            lo = 0.0;
            hi = WALK_MAX_S;
        } else if (cmd->op == SCRIPT_POSE) {
            hi = i == 0 ? YAW_MAX_DEG : PITCH_MAX_DEG;
            lo = -hi;
        }
        if (num_parse_real(tok[i + 1], lo, hi, &cmd->arg[i]) < 0)
            return cvre_fail(err, errlen, -EINVAL, "%s: bad number '%.40s' (want a finite number in [%g, %g]): %s",
                             commands[k].name, tok[i + 1], lo, hi, commands[k].usage);
    }
    return 1;
}

void script_cmd_clear(script_cmd *cmd)
{
    free(cmd->file);
    cmd->file = NULL;
}
