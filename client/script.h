/*
 * script.h: the scripted and interactive client: one connection that runs
 * commands (move, walk, wait, ping, import, place, remove, quit) in order
 * once joined, while every received event is printed (events.h).
 * script_parse.c holds the command language, script_upload.c the imports'
 * uploads and placing, script.c the runner and its input.
 *
 * Commands come from a file, read and checked whole before connecting; from
 * standard input when it is a pipe or a terminal, line by line as they are
 * typed; or from standard input read whole when it is a regular file.
 */
#ifndef CVRE_CLIENT_SCRIPT_H
#define CVRE_CLIENT_SCRIPT_H

#include "session.h"
#include "ev.h"

/* Longest command line; longer ones are an error, not silently cut. */
#define SCRIPT_LINE_MAX 1024

enum script_op {
    SCRIPT_MOVE,
    SCRIPT_WALK,
    SCRIPT_WAIT,
    SCRIPT_PING,
    SCRIPT_POSE,
    SCRIPT_IMPORT,
    SCRIPT_PLACE,
    SCRIPT_REMOVE,
    SCRIPT_FETCH,
    SCRIPT_QUIT
};

/* Which point of an imported model "at X Y Z" names. */
enum script_anchor {
    SCRIPT_ANCHOR_ORIGIN, /* the model file's origin (the wire's transform) */
    SCRIPT_ANCHOR_BASE,   /* the bottom centre of the box around its collision boxes */
};

typedef struct script_cmd {
    int op;        /* enum script_op */
    double arg[3]; /* move: x y z; walk: dx dz seconds; wait: ms; pose: yaw pitch (degrees); import, place: x y z */
    uint32_t object_id; /* place, remove, fetch */
    double yaw_deg;     /* import, place: degrees about +y */
    double size;        /* import, place: uniform object scale */
    int has_yaw, has_size; /* place: given (else the object's current ones) */
    char *file;         /* import, fetch: as written, owned: script_cmd_clear() frees it */
    /* import only */
    char name[PROTO_OBJECT_NAME_MAX + 1]; /* --name, or "": the file's base name */
    int up_axis;        /* enum proto_up_axis */
    double unit_scale;  /* file units to metres */
    int anchor;         /* enum script_anchor */
    int drop;           /* --drop: lower (or raise) the box onto the surface under it */
} script_cmd;

/*
 * Parses one line (without its newline). Returns 1 and fills *cmd for a
 * command, 0 for a blank or comment line, -EINVAL with a message in err (which
 * does not name the line; the caller knows it) for anything else, including
 * numbers that are not finite or do not fit their range. Words are split at
 * blanks; a word in double quotes ("my model.obj") may hold blanks and '#'.
 * A command that returned 1 may own memory: release it with
 * script_cmd_clear(). Only the syntax is checked: whether an import's file
 * can be read is found out when it runs.
 */
int script_parse_line(const char *line, script_cmd *cmd, char *err, size_t errlen);
/* Frees what *cmd owns; it may be cleared again. */
void script_cmd_clear(script_cmd *cmd);
/* The command's word ("move", "import", ...) for an enum script_op. */
const char *script_op_name(int op);

typedef struct script_opts {
    session_params net;
    double rate;      /* moves per second while walking */
    const char *file; /* NULL: standard input */
    session_credential login; /* what the join carries */
    int json;         /* JSON lines even when a person types at a terminal */
} script_opts;

typedef struct script script;

/*
 * Loads the commands (or sets up reading them) and starts connecting.
 * Returns NULL with *exit_code set when it cannot start: 2 for a bad script,
 * 1 for an unreadable file or an unresolvable host. Stops the loop when the
 * connection has ended.
 */
script *script_create(ev_loop *loop, const script_opts *opts, int *exit_code);
/* SIGINT or SIGTERM: say bye and end; a second one ends at once. */
void script_interrupt(script *s);
/* 0 after a clean end, 1 if the connection failed or ended before quit,
 * 2 after a script error. Meaningful once the loop has stopped. */
int script_exit_code(const script *s);
void script_free(script *s);

#endif
