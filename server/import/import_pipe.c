#include "import_pipe.h"

#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "err.h"
#include "le.h"

_Static_assert(IMPORT_PIPE_HINT_MAX <= 255u, "the hint's length is a u8");
_Static_assert(IMPORT_PIPE_MESSAGE_MAX <= 65535u, "the message's length is a u16");

static const uint8_t request_magic[4] = {'C', 'V', 'R', 'Q'};
static const uint8_t answer_magic[4] = {'C', 'V', 'R', 'A'};

size_t import_pipe_request_head(uint8_t *out, const char *hint, const import_options *opt,
                                uint32_t data_len)
{
    size_t hl = hint ? strnlen(hint, IMPORT_PIPE_HINT_MAX) : 0, k = 0;

    memcpy(out, request_magic, 4);
    le_put_u32(out + 4, IMPORT_PIPE_VERSION);
    out[8] = opt->z_up ? 1 : 0;
    le_put_f32(out + 9, opt->unit_scale);
    le_put_u32(out + 13, opt->max_triangles);
    out[17] = (uint8_t)hl;
    k = 18;
    memcpy(out + k, hint ? hint : "", hl);
    k += hl;
    le_put_u32(out + k, data_len);
    return k + 4;
}

long import_pipe_request_parse(const uint8_t *p, size_t n, import_options *opt, char *hint,
                               uint32_t *data_len)
{
    size_t hl;

    if (n < 18)
        return n >= 4 && memcmp(p, request_magic, 4) != 0 ? -EPROTO : 0;
    if (memcmp(p, request_magic, 4) != 0 || le_get_u32(p + 4) != IMPORT_PIPE_VERSION || p[8] > 1)
        return -EPROTO;
    hl = p[17];
    if (hl > IMPORT_PIPE_HINT_MAX)
        return -EPROTO;
    if (n < 18 + hl + 4)
        return 0;
    opt->z_up = p[8];
    opt->unit_scale = le_get_f32(p + 9);
    opt->max_triangles = le_get_u32(p + 13);
    memcpy(hint, p + 18, hl);
    hint[hl] = 0;
    *data_len = le_get_u32(p + 18 + hl);
    return (long)(18 + hl + 4);
}

size_t import_pipe_answer_head_encode(uint8_t *out, int status, const char *message, const import_mesh *m)
{
    size_t ml = message ? strnlen(message, IMPORT_PIPE_MESSAGE_MAX) : 0, k;

    memcpy(out, answer_magic, 4);
    le_put_u32(out + 4, IMPORT_PIPE_VERSION);
    le_put_u32(out + 8, (uint32_t)status);
    le_put_u16(out + 12, (uint16_t)ml);
    memcpy(out + 14, message ? message : "", ml);
    k = 14 + ml;
    if (status != 0)
        return k;
    le_put_u32(out + k, m->ntris);
    k += 4;
    for (int i = 0; i < 3; i++, k += 4)
        le_put_f32(out + k, m->min[i]);
    for (int i = 0; i < 3; i++, k += 4)
        le_put_f32(out + k, m->max[i]);
    return k;
}

void import_pipe_tris_to_le(float *tris, size_t nfloats)
{
    for (size_t i = 0; i < nfloats; i++)
        le_put_f32((uint8_t *)&tris[i], tris[i]); /* the same bytes on a little-endian host */
}

int import_pipe_answer_encode(int status, const char *message, const import_mesh *m, uint8_t **out,
                              size_t *outlen)
{
    uint8_t head[IMPORT_PIPE_ANSWER_HEAD];
    size_t k = import_pipe_answer_head_encode(head, status, message, m);
    size_t tail = status == 0 ? (size_t)m->ntris * 36u : 0;
    uint8_t *b = cvre_malloc(k + tail);

    *out = NULL;
    *outlen = 0;
    if (!b)
        return -ENOMEM;
    memcpy(b, head, k);
    for (size_t i = 0; i < tail / 4; i++)
        le_put_f32(b + k + 4 * i, m->tris[i]);
    *out = b;
    *outlen = k + tail;
    return 0;
}

/* The helper's message into err (errlen >= 1), one line of printable ASCII. */
static void copy_message(const uint8_t *p, size_t n, char *err, size_t errlen)
{
    size_t k;

    for (k = 0; k < n && k + 1 < errlen; k++)
        err[k] = p[k] >= 0x20 && p[k] <= 0x7e ? (char)p[k] : '?';
    err[k] = 0;
}

long import_pipe_answer_head(const uint8_t *p, size_t n, uint32_t max_triangles, import_pipe_head *h,
                             char *err, size_t errlen)
{
    size_t ml;

    if (n < 14)
        return n >= 4 && memcmp(p, answer_magic, 4) != 0
                   ? cvre_fail(err, errlen, -EPROTO, "the importer's answer has no valid header")
                   : 0;
    if (memcmp(p, answer_magic, 4) != 0 || le_get_u32(p + 4) != IMPORT_PIPE_VERSION)
        return cvre_fail(err, errlen, -EPROTO, "the importer's answer has no valid header");
    h->status = (int32_t)le_get_u32(p + 8);
    ml = le_get_u16(p + 12);
    if (ml > IMPORT_PIPE_MESSAGE_MAX)
        return cvre_fail(err, errlen, -EPROTO, "the importer's message is too long");
    if (h->status != 0 && h->status != -EINVAL && h->status != -EFBIG && h->status != -ENOMEM)
        return cvre_fail(err, errlen, -EPROTO, "the importer answered status %d", (int)h->status);
    if (n < 14 + ml + (h->status == 0 ? 28u : 0u))
        return 0;
    copy_message(p + 14, ml, h->message, sizeof h->message);
    h->ntris = 0;
    if (h->status != 0)
        return (long)(14 + ml);
    h->ntris = le_get_u32(p + 14 + ml);
    if (h->ntris == 0)
        return cvre_fail(err, errlen, -EPROTO, "the importer answered no triangles");
    if (h->ntris > max_triangles) {
        if (errlen)
            snprintf(err, errlen, "the importer answered %u triangles, over the limit of %u", h->ntris,
                     max_triangles);
        return -EFBIG;
    }
    for (int i = 0; i < 6; i++)
        h->box[i] = le_get_f32(p + 14 + ml + 4 + 4 * (size_t)i);
    return (long)(14 + ml + 28);
}

int import_pipe_answer_tris(float *tris, const import_pipe_head *h, char *err, size_t errlen)
{
    float got[6] = {INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY};
    int ok = 1;

    for (size_t i = 0; i < (size_t)h->ntris * 9u; i++) {
        float v = le_get_f32((const uint8_t *)&tris[i]);
        int axis = (int)(i % 3);
        if (!isfinite(v) || fabsf(v) > IMPORT_MAX_COORD)
            return cvre_fail(err, errlen, -EPROTO, "the importer answered a coordinate that is not finite or beyond %.0f km",
                       IMPORT_MAX_COORD / 1000.0);
        tris[i] = v;
        got[axis] = fminf(got[axis], v);
        got[axis + 3] = fmaxf(got[axis + 3], v);
    }
    for (int i = 0; i < 6; i++)
        ok &= got[i] == h->box[i]; /* by value: -0 is 0 */
    return ok ? 0 : cvre_fail(err, errlen, -EPROTO, "the importer's box is not its triangles' box");
}

int import_pipe_answer(const uint8_t *p, size_t n, uint32_t max_triangles, import_mesh *out,
                       char *err, size_t errlen)
{
    import_pipe_head h;
    long k = import_pipe_answer_head(p, n, max_triangles, &h, err, errlen);
    float *tris;
    int rc;

    memset(out, 0, sizeof *out);
    if (k < 0)
        return (int)k;
    if (k == 0)
        return cvre_fail(err, errlen, -EPROTO, "the importer's answer ends in its header (%zu bytes)", n);
    if ((uint64_t)(n - (size_t)k) != (uint64_t)h.ntris * 36u)
        return cvre_fail(err, errlen, -EPROTO, "the importer's answer holds %zu bytes after its header for %u triangles",
                   n - (size_t)k, h.ntris);
    if (h.status != 0) {
        if (errlen)
            snprintf(err, errlen, "%s", h.message);
        return h.status;
    }
    tris = cvre_malloc((size_t)h.ntris * 36u);
    if (!tris) {
        if (errlen)
            snprintf(err, errlen, "out of memory reading the importer's answer");
        return -ENOMEM;
    }
    memcpy(tris, p + k, (size_t)h.ntris * 36u);
    rc = import_pipe_answer_tris(tris, &h, err, errlen);
    if (rc != 0) {
        free(tris);
        return rc;
    }
    out->tris = tris;
    out->ntris = h.ntris;
    memcpy(out->min, h.box, sizeof out->min);
    memcpy(out->max, h.box + 3, sizeof out->max);
    if (errlen)
        err[0] = 0;
    return 0;
}
