/*
 * scriptInt.h: what script.c (the runner) and script_upload.c (imports)
 * share: the runner's state and the few calls each makes into the other.
 * Nothing outside these files includes it.
 */
#ifndef CVRE_CLIENT_SCRIPTINT_H
#define CVRE_CLIENT_SCRIPTINT_H

#include <stdint.h>

#include "known.h"
#include "script.h"

#define NS_PER_MS 1000000ull
#define NS_PER_S 1000000000ull

/* How long place and remove (and the second placing of an import that is
 * anchored or dropped) wait for the server's answer. */
#define OBJECT_WAIT_NS (5ull * NS_PER_S)
/* The window probes' pings carry this bit in their stamps (script_upload.c);
 * the ping command's and the keepalive's stamps are clock readings in
 * microseconds, which never reach bit 63. */
#define IMPORT_PROBE_MARK (1ull << 63)

/* Where an import stands: its frames go out in this order, each only once
 * the backlog is empty; then it waits for the server's answer, and, when
 * the model is anchored by its base or dropped, for the answer to the
 * OBJECT_PLACE that moves it there. */
enum import_phase { IMPORT_NONE, IMPORT_BEGIN, IMPORT_CHUNKS, IMPORT_END, IMPORT_WAIT, IMPORT_SETTLE };

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
    int terminal;   /* interactive, and stdout a terminal: terminal.h's lines, not JSON */
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
    uint32_t imp_object; /* the object it made, once the server said so; 0 before */
    uint64_t t_progress;
    uint32_t last_upload_id;
    uint8_t chunk[PROTO_CHUNK_MAX];

    /* fetch: the mesh of the running command as its chunks come, and the
     * meshes fetched this session, by hash (script_fetch.c) */
    uint8_t fetch_hash[PROTO_MESH_HASH_SIZE];
    uint32_t fetch_tris;
    uint8_t *fetch_buf;
    uint32_t fetch_len, fetch_total;
    struct fetched *fetched;
    size_t nfetched;

    /* Objects the server told us about: a place that does not name a yaw
     * or a size keeps the current ones, and --drop lands on their boxes. */
    known *objs;

    int keepalive_timer;
    int linger_timer;
    int start_timer;
};

/* script.c: the running command's end and the runner's timer. */

/* Ends the running import, place or remove with its done event without
 * advancing to the next command. result is "ok", "rejected", "timeout" or
 * "failed"; o is the OBJECT_INFO that answered it (NULL if none), whose
 * object id and boxes the done event reports. */
void script__obj_done(script *s, const char *result, const proto_object_info *o);
/* The same, then runs what is queued next. */
void script__obj_finish(script *s, const char *result, const proto_object_info *o);
/* A local failure of an object command: an error event with code 0, and
 * the same text on stderr unless the event itself went to the terminal. */
void script__obj_error(const script *s, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
ev_timer_fn script__on_cmd_timer;

/* script_upload.c: the import command. */

/* Starts the running import: checks the file, then sends what it can. A
 * file that cannot be read ends the command at once ("failed"). */
void script__import_start(script *s);
/* Sends what is next of the upload while the backlog is empty. Returns 0,
 * or -EIO after reporting that the file could not be read (the caller ends
 * the command as "failed"). */
int script__import_pump(script *s);
/* The pong of a window probe (stamp has IMPORT_PROBE_MARK). */
void script__import_probed(script *s, uint64_t stamp);
/* An OBJECT_INFO while an import runs: its answer, or that of its second
 * placing; anything else is ignored. */
void script__import_object(script *s, const proto_object_info *o);
/* The import timer's check: gives up after a time without progress. */
void script__import_check(script *s, uint64_t now);
/* script_fetch.c: the fetch command. */

/* Starts the running fetch: from the session's meshes, or a request. */
void script__fetch_start(script *s);
/* A MESH_CHUNK; the last one writes the file and ends the command. */
void script__fetch_chunk(script *s, const proto_mesh_chunk *ch);
/* The fetch timer's check: gives up after a time without a chunk. */
void script__fetch_check(script *s, uint64_t now);
/* Frees the running fetch's partial mesh; the cache, at the end. */
void script__fetch_release(script *s);
void script__fetch_free_cache(script *s);

/* Yaw in radians from degrees, reduced to one turn first so that a large
 * angle loses nothing in the f32. */
float script__yaw_radians(double deg);

#endif
