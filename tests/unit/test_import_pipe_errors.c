/* The importer's pipe where it fails: answers with a bad head (magic,
 * version, no triangles), running out of memory on either side, and the
 * triangles' byte order on the helper's side. */
#include <errno.h>
#include <setjmp.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdlib.h>
#include <string.h>

#include <cmocka.h>

#include "alloc.h"
#include "le.h"
#include "import_pipe.h"

/* A good answer with one triangle, malloc'd; *n its length. */
static uint8_t *one_triangle(size_t *n)
{
    static float tris[9] = {0, 0, 0, 1, 0, 0, 0, 1, 0};
    import_mesh m = {tris, 1, {0, 0, 0}, {1, 1, 0}};
    uint8_t *b;

    assert_int_equal(import_pipe_answer_encode(0, NULL, &m, &b, n), 0);
    return b;
}

static void test_bad_heads(void **state)
{
    import_pipe_head h;
    import_mesh m;
    char err[256];
    size_t n;
    uint8_t *b = one_triangle(&n);

    (void)state;
    assert_int_equal(import_pipe_answer(b, n, 10, &m, err, sizeof err), 0);
    import_mesh_free(&m);

    /* a wrong magic is wrong as soon as its four bytes are in */
    b[0] = 'X';
    for (size_t k = 0; k < 4; k++)
        assert_int_equal(import_pipe_answer_head(b, k, 10, &h, err, sizeof err), 0);
    for (size_t k = 4; k <= n; k++) {
        err[0] = 0;
        assert_int_equal(import_pipe_answer_head(b, k, 10, &h, err, sizeof err), -EPROTO);
        assert_string_equal(err, "the importer's answer has no valid header");
    }
    b[0] = 'C';

    le_put_u32(b + 4, IMPORT_PIPE_VERSION + 1);
    assert_int_equal(import_pipe_answer(b, n, 10, &m, err, sizeof err), -EPROTO);
    assert_string_equal(err, "the importer's answer has no valid header");
    le_put_u32(b + 4, IMPORT_PIPE_VERSION);

    le_put_u32(b + 14, 0); /* a success without triangles */
    assert_int_equal(import_pipe_answer(b, n, 10, &m, err, sizeof err), -EPROTO);
    assert_string_equal(err, "the importer answered no triangles");
    assert_null(m.tris);

    /* no room for a message: the status still says what happened */
    le_put_u32(b + 14, 1);
    assert_int_equal(import_pipe_answer(b, n, 0, &m, err, 0), -EFBIG);
    assert_int_equal(import_pipe_answer(b, n, 10, &m, err, 0), 0);
    import_mesh_free(&m);
    free(b);
}

static void test_out_of_memory(void **state)
{
    import_mesh m;
    char err[256];
    size_t n = 1;
    uint8_t *b = one_triangle(&n), *c = (uint8_t *)"x";

    (void)state;
    cvre_alloc_fail_after(0);
    assert_int_equal(import_pipe_answer(b, n, 10, &m, err, sizeof err), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_string_equal(err, "out of memory reading the importer's answer");
    assert_null(m.tris);

    cvre_alloc_fail_after(0);
    assert_int_equal(import_pipe_answer_encode(0, NULL, &m, &c, &n), -ENOMEM);
    cvre_alloc_fail_after(-1);
    assert_null(c);
    assert_int_equal(n, 0);
    free(b);
}

/* What cvre-import writes after the head: each float's bytes in
 * little-endian order, whatever the host's. */
static void test_triangles_to_le(void **state)
{
    float v[3] = {1.0f, -2.0f, 0.5f};
    static const uint8_t want[12] = {0x00, 0x00, 0x80, 0x3f, 0x00, 0x00, 0x00, 0xc0, 0x00, 0x00, 0x00, 0x3f};

    (void)state;
    import_pipe_tris_to_le(v, 3);
    assert_memory_equal(v, want, sizeof want);
    import_pipe_tris_to_le(v, 0); /* nothing to do */
    assert_memory_equal(v, want, sizeof want);
}

int main(void)
{
    const struct CMUnitTest tests[] = {
        cmocka_unit_test(test_bad_heads),
        cmocka_unit_test(test_out_of_memory),
        cmocka_unit_test(test_triangles_to_le),
    };
    return cmocka_run_group_tests(tests, NULL, NULL);
}
