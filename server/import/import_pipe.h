/*
 * import_pipe.h: the length-checked binary form in which the server hands
 * an upload to the isolated importer (cvre-import) and takes triangles
 * back, over a pair of pipes.
 *
 * Request, server to helper (little-endian):
 *   "CVRQ" u32 version  u8 z_up  f32 unit_scale  u32 max_triangles
 *   u8 hint_len  hint[hint_len]  u32 data_len  data[data_len]
 * Answer, helper to server:
 *   "CVRA" u32 version  i32 status (0 or -errno from import_model)
 *   u16 message_len  message[message_len]
 *   and when status is 0: u32 ntris  f32 min[3]  f32 max[3]  f32 tris[9 * ntris]
 *
 * The helper is treated as a peer on the network: the answer is decoded by
 * import_pipe_answer_head and import_pipe_answer_tris (or, for a whole
 * answer in memory, import_pipe_answer), which check every count against
 * what was asked, every coordinate for finiteness and against the box, and
 * the whole length. The triangles travel as they lie in memory on a
 * little-endian host, so that neither side copies them again.
 */
#ifndef CVRE_IMPORT_PIPE_H
#define CVRE_IMPORT_PIPE_H

#include <stddef.h>
#include <stdint.h>

#include "import.h"

#define IMPORT_PIPE_VERSION 1u
/* Longest hint (a file extension) and message carried. */
#define IMPORT_PIPE_HINT_MAX 16u
#define IMPORT_PIPE_MESSAGE_MAX 1024u
/* Bytes of a request before its data, at most. */
#define IMPORT_PIPE_REQUEST_HEAD (4u + 4u + 1u + 4u + 4u + 1u + IMPORT_PIPE_HINT_MAX + 4u)
/* Bytes of an answer before its triangles, at most. */
#define IMPORT_PIPE_ANSWER_HEAD (4u + 4u + 4u + 2u + IMPORT_PIPE_MESSAGE_MAX + 4u + 24u)

/* Writes a request's head (everything before the data) into out, which
 * holds IMPORT_PIPE_REQUEST_HEAD bytes; returns its length. hint may be
 * NULL; a longer hint than IMPORT_PIPE_HINT_MAX is cut (import_model would
 * refuse it as unsupported either way). */
size_t import_pipe_request_head(uint8_t *out, const char *hint, const import_options *opt,
                                uint32_t data_len);

/* Decodes a request head from p[0..n). Returns the head's length and fills
 * *opt, hint (IMPORT_PIPE_HINT_MAX + 1 bytes, NUL-terminated) and
 * *data_len; 0 when more bytes are needed; -EPROTO when it is malformed. */
long import_pipe_request_parse(const uint8_t *p, size_t n, import_options *opt, char *hint,
                               uint32_t *data_len);

/* An answer's head (everything before the triangles) into out, which
 * holds IMPORT_PIPE_ANSWER_HEAD bytes; returns its length. m is read only
 * when status is 0; its triangles follow as m->ntris * 9 little-endian
 * floats (import_pipe_tris_to_le turns them so in place). */
size_t import_pipe_answer_head_encode(uint8_t *out, int status, const char *message, const import_mesh *m);
void import_pipe_tris_to_le(float *tris, size_t nfloats);
/* A whole answer in one malloc'd buffer (*out, *outlen; the caller
 * frees). Returns 0 or -ENOMEM. */
int import_pipe_answer_encode(int status, const char *message, const import_mesh *m, uint8_t **out,
                              size_t *outlen);

/* What an answer's head says. */
typedef struct import_pipe_head {
    int status;                              /* 0, -EINVAL, -EFBIG or -ENOMEM */
    char message[IMPORT_PIPE_MESSAGE_MAX + 1]; /* printable ASCII */
    uint32_t ntris;                          /* 1..max_triangles when status is 0 */
    float box[6];                            /* min x y z, max x y z */
} import_pipe_head;

/* Decodes an answer's head from p[0..n): its length, 0 when more bytes are
 * needed, -EFBIG with err for a count over max_triangles, or -EPROTO with
 * err (a bad header, status or message length, a count of 0). The
 * triangles come next: for status 0, exactly h->ntris * 36 bytes, then the
 * end; otherwise the end. */
long import_pipe_answer_head(const uint8_t *p, size_t n, uint32_t max_triangles, import_pipe_head *h,
                             char *err, size_t errlen);
/* Checks the h->ntris * 9 floats read raw into tris (little-endian on the
 * wire; turned in place): finite, within IMPORT_MAX_COORD, and exactly
 * spanning h->box. 0 or -EPROTO with err. */
int import_pipe_answer_tris(float *tris, const import_pipe_head *h, char *err, size_t errlen);

/*
 * Decodes a whole answer p[0..n) to a request for at most max_triangles
 * triangles. Returns the helper's status with its message in err (and, for
 * 0, *out owning a new array of triangles), -EFBIG for a count over
 * max_triangles, or -EPROTO with err saying what was wrong when the answer
 * is malformed: short or long, a status that import_model never returns, a
 * coordinate that is not finite or lies outside the box it gives, or a box
 * that is not the triangles' own. On any failure *out is zeroed.
 */
int import_pipe_answer(const uint8_t *p, size_t n, uint32_t max_triangles, import_mesh *out,
                       char *err, size_t errlen);

#endif
