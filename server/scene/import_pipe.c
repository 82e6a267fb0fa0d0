#include "import_pipe.h"

#include <errno.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "alloc.h"
#include "le.h"

_Static_assert(IMPORT_PIPE_HINT_MAX <= 255u, "the hint's length is a u8");
_Static_assert(IMPORT_PIPE_MESSAGE_MAX <= 65535u, "the message's length is a u16");

static const uint8_t request_magic[4] = {'C', 'V', 'R', 'Q'};
static const uint8_t answer_magic[4] = {'C', 'V', 'R', 'A'};

uint64_t import_pipe_answer_max(uint32_t max_triangles)
{
    return IMPORT_PIPE_ANSWER_HEAD + (uint64_t)max_triangles * 36u;
}

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
        return n >= 4 && memcmp(p, request_magic, 4) != 0 ? -1 : 0;
    if (memcmp(p, request_magic, 4) != 0 || le_get_u32(p + 4) != IMPORT_PIPE_VERSION || p[8] > 1)
        return -1;
    hl = p[17];
    if (hl > IMPORT_PIPE_HINT_MAX)
        return -1;
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

int import_pipe_answer_encode(int status, const char *message, const import_mesh *m, uint8_t **out,
                              size_t *outlen)
{
    size_t ml = message ? strnlen(message, IMPORT_PIPE_MESSAGE_MAX) : 0;
    size_t n = 14 + ml + (status == 0 ? 28 + (size_t)m->ntris * 36u : 0), k;
    uint8_t *b = cvre_malloc(n);

    *out = NULL;
    *outlen = 0;
    if (!b)
        return -ENOMEM;
    memcpy(b, answer_magic, 4);
    le_put_u32(b + 4, IMPORT_PIPE_VERSION);
    le_put_u32(b + 8, (uint32_t)status);
    le_put_u16(b + 12, (uint16_t)ml);
    memcpy(b + 14, message ? message : "", ml);
    k = 14 + ml;
    if (status == 0) {
        le_put_u32(b + k, m->ntris);
        k += 4;
        for (int i = 0; i < 3; i++, k += 4)
            le_put_f32(b + k, m->min[i]);
        for (int i = 0; i < 3; i++, k += 4)
            le_put_f32(b + k, m->max[i]);
        for (size_t i = 0; i < (size_t)m->ntris * 9u; i++, k += 4)
            le_put_f32(b + k, m->tris[i]);
    }
    *out = b;
    *outlen = n;
    return 0;
}

/* Formats a reason into err and returns -EPROTO. */
__attribute__((format(printf, 3, 4))) static int bad(char *err, size_t errlen, const char *fmt, ...)
{
    va_list ap;

    if (errlen) {
        va_start(ap, fmt);
        vsnprintf(err, errlen, fmt, ap);
        va_end(ap);
    }
    return -EPROTO;
}

/* The helper's message into err, one line of printable ASCII. */
static void copy_message(const uint8_t *p, size_t n, char *err, size_t errlen)
{
    size_t k;

    if (!errlen)
        return;
    for (k = 0; k < n && k + 1 < errlen; k++)
        err[k] = p[k] >= 0x20 && p[k] <= 0x7e ? (char)p[k] : '?';
    err[k] = 0;
}

int import_pipe_answer(const uint8_t *p, size_t n, uint32_t max_triangles, import_mesh *out,
                       char *err, size_t errlen)
{
    size_t ml, k;
    int32_t status;
    uint32_t ntris;
    float box[6], got[6] = {INFINITY, INFINITY, INFINITY, -INFINITY, -INFINITY, -INFINITY};
    float *tris;
    int ok = 1;

    memset(out, 0, sizeof *out);
    if (n < 14 || memcmp(p, answer_magic, 4) != 0 || le_get_u32(p + 4) != IMPORT_PIPE_VERSION)
        return bad(err, errlen, "the importer's answer has no valid header (%zu bytes)", n);
    status = (int32_t)le_get_u32(p + 8);
    ml = le_get_u16(p + 12);
    if (ml > IMPORT_PIPE_MESSAGE_MAX || 14 + ml > n)
        return bad(err, errlen, "the importer's message overruns its answer");
    if (status != 0) {
        if (status != -EINVAL && status != -EFBIG && status != -ENOMEM)
            return bad(err, errlen, "the importer answered status %d", (int)status);
        if (14 + ml != n)
            return bad(err, errlen, "the importer's answer has %zu bytes too many", n - 14 - ml);
        copy_message(p + 14, ml, err, errlen);
        return status;
    }
    k = 14 + ml;
    if (n - k < 28)
        return bad(err, errlen, "the importer's answer ends before its triangle count");
    ntris = le_get_u32(p + k);
    if (ntris == 0 || ntris > max_triangles)
        return bad(err, errlen, "the importer answered %u triangles (1 to %u allowed)", ntris,
                   max_triangles);
    if ((uint64_t)(n - k - 28) != (uint64_t)ntris * 36u)
        return bad(err, errlen, "the importer's answer holds %zu bytes for %u triangles",
                   n - k - 28, ntris);
    for (int i = 0; i < 6; i++)
        box[i] = le_get_f32(p + k + 4 + 4 * (size_t)i);
    tris = cvre_malloc((size_t)ntris * 36u);
    if (!tris) {
        if (errlen)
            snprintf(err, errlen, "out of memory reading the importer's answer");
        return -ENOMEM;
    }
    k += 28;
    for (size_t i = 0; i < (size_t)ntris * 9u; i++, k += 4) {
        float v = le_get_f32(p + k);
        int axis = (int)(i % 3);
        if (!isfinite(v) || fabsf(v) > IMPORT_MAX_COORD) {
            free(tris);
            return bad(err, errlen, "the importer answered a coordinate that is not finite or beyond %.0f km",
                       IMPORT_MAX_COORD / 1000.0);
        }
        tris[i] = v;
        got[axis] = fminf(got[axis], v);
        got[axis + 3] = fmaxf(got[axis + 3], v);
    }
    for (int i = 0; i < 6; i++)
        ok &= got[i] == box[i]; /* by value: -0 is 0 */
    if (!ok) {
        free(tris);
        return bad(err, errlen, "the importer's box is not its triangles' box");
    }
    out->tris = tris;
    out->ntris = ntris;
    memcpy(out->min, box, sizeof out->min);
    memcpy(out->max, box + 3, sizeof out->max);
    if (errlen)
        err[0] = 0;
    return 0;
}
