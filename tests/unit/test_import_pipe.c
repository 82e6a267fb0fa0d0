/* The importer's pipe: requests round-trip, and every malformed answer a
 * broken or hostile helper could send is refused with -EPROTO. */
#include <errno.h>
#include <math.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "le.h"
#include "import_pipe.h"

static void test_request_round_trip(void **state)
{
    import_options opt = {1, 0.01f, 12345}, got;
    uint8_t head[IMPORT_PIPE_REQUEST_HEAD];
    char hint[IMPORT_PIPE_HINT_MAX + 1];
    uint32_t len = 0;
    size_t n = import_pipe_request_head(head, "glb", &opt, 777);

    (void)state;
    for (size_t k = 0; k < n; k++) /* a prefix asks for more */
        assert_int_equal(import_pipe_request_parse(head, k, &got, hint, &len), 0);
    assert_int_equal(import_pipe_request_parse(head, n, &got, hint, &len), (long)n);
    assert_string_equal(hint, "glb");
    assert_int_equal(len, 777);
    assert_int_equal(got.z_up, 1);
    assert_true(got.unit_scale == 0.01f && got.max_triangles == 12345);
    head[0] = 'X';
    assert_int_equal(import_pipe_request_parse(head, n, &got, hint, &len), -EPROTO);
    head[0] = 'C';
    head[17] = IMPORT_PIPE_HINT_MAX + 1; /* hint longer than allowed */
    assert_int_equal(import_pipe_request_parse(head, n, &got, hint, &len), -EPROTO);
}

/* A good answer with two triangles. */
static uint8_t *two_triangles(size_t *n)
{
    static float tris[18] = {0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1, 1, 1, 1, -1, 0, 0};
    import_mesh m = {tris, 2, {-1, 0, 0}, {1, 1, 1}};
    uint8_t *b;

    assert_int_equal(import_pipe_answer_encode(0, "", &m, &b, n), 0);
    return b;
}

static int decode(const uint8_t *b, size_t n, uint32_t max, char *err)
{
    import_mesh m;
    int rc = import_pipe_answer(b, n, max, &m, err, 256);

    if (rc == 0) {
        assert_int_equal(m.ntris, 2);
        assert_true(m.min[0] == -1 && m.max[2] == 1);
        import_mesh_free(&m);
    } else {
        assert_null(m.tris);
    }
    return rc;
}

static void test_answers(void **state)
{
    char err[256];
    size_t n;
    uint8_t *b = two_triangles(&n), *c;

    (void)state;
    assert_int_equal(decode(b, n, 2, err), 0);
    for (size_t k = 0; k < n; k++) /* every truncation */
        assert_int_equal(decode(b, k, 2, err), -EPROTO);
    assert_int_equal(decode(b, n, 1, err), -EFBIG); /* over the limit asked */
    assert_non_null(strstr(err, "2 triangles, over the limit of 1"));
    c = malloc(n + 1);
    memcpy(c, b, n);
    c[n] = 0;
    assert_int_equal(decode(c, n + 1, 2, err), -EPROTO); /* a byte too many */
    le_put_f32(b + 14 + 28 + 4 * 4, NAN);
    assert_int_equal(decode(b, n, 2, err), -EPROTO);
    assert_non_null(strstr(err, "not finite"));
    le_put_f32(b + 14 + 28 + 4 * 4, 1e30f); /* finite, but far beyond any world */
    assert_int_equal(decode(b, n, 2, err), -EPROTO);
    assert_non_null(strstr(err, "beyond"));
    le_put_f32(b + 14 + 28 + 4 * 4, 5.0f); /* finite, but outside the box */
    assert_int_equal(decode(b, n, 2, err), -EPROTO);
    assert_non_null(strstr(err, "box"));
    free(b);
    free(c);

    /* refusals carry the helper's message, made printable */
    assert_int_equal(import_pipe_answer_encode(-EINVAL, "bad\nfile\x80", NULL, &b, &n), 0);
    assert_int_equal(decode(b, n, 2, err), -EINVAL);
    assert_string_equal(err, "bad?file?");
    le_put_u32(b + 8, (uint32_t)-EPERM); /* a status import_model never returns */
    assert_int_equal(decode(b, n, 2, err), -EPROTO);
    le_put_u32(b + 8, (uint32_t)-EINVAL);
    le_put_u16(b + 12, 60000); /* a message past the end */
    assert_int_equal(decode(b, n, 2, err), -EPROTO);
    free(b);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_request_round_trip),
        cmocka_unit_test(test_answers),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
