/*
 * fz_import.c: the test every model target runs on its inputs
 * (fuzz_glb, fuzz_obj, fuzz_ply, fuzz_stl): import_model() with the
 * target's hint and with none, each held to its contract.
 */
#include <errno.h>
#include <math.h>
#include <stdio.h>
#include <string.h>

#include "fz.h"
#include "import.h"

/* What the inputs reached, by hint (the target's, none), so that a
 * generator that stops reaching Assimp, or its success path, shows. */
static unsigned long n_imports[2], n_ok[2];

/*
 * Imports data and checks import_model()'s promises: a code with a
 * one-line message and a zeroed mesh, or a mesh of finite vertices whose
 * box is exactly theirs. Returns the code; *m owns the mesh on success.
 */
static int import_checked(const uint8_t *data, size_t size, const char *hint,
                          const import_options *o, import_mesh *m)
{
    char err[256];
    float lo[3] = {INFINITY, INFINITY, INFINITY}, hi[3] = {-INFINITY, -INFINITY, -INFINITY};
    int rc;

    memset(err, 'x', sizeof err);
    rc = import_model(data, size, hint, o, m, err, sizeof err);
    FZ_CHECK(memchr(err, 0, sizeof err) != NULL && !strchr(err, '\n'));
    if (rc != 0) {
        FZ_CHECK(rc == -EINVAL || rc == -EFBIG || rc == -ENOMEM);
        FZ_CHECK(err[0] != 0 && m->tris == NULL && m->ntris == 0);
        return rc;
    }
    FZ_CHECK(err[0] == 0 && m->tris != NULL && m->ntris >= 1 && m->ntris <= o->max_triangles);
    for (size_t i = 0; i < (size_t)m->ntris * 9; i++) {
        float v = m->tris[i];
        FZ_CHECK(isfinite(v));
        if (v < lo[i % 3])
            lo[i % 3] = v;
        if (v > hi[i % 3])
            hi[i % 3] = v;
    }
    for (int k = 0; k < 3; k++)
        FZ_CHECK(m->min[k] == lo[k] && m->max[k] == hi[k]);
    return rc;
}

/*
 * The content decides the format, so what imports without a hint imports
 * the same with the format's own. The second import is also Z-up:
 * (x,y,z) becomes (x,z,-y) exactly, since only signs and places change.
 */
int LLVMFuzzerTestOneInput(const uint8_t *data, size_t size)
{
    /* a triangle limit small enough that huge inputs fail fast */
    const import_options y_up = {0, 1.0f, 1000000}, z_up = {1, 1.0f, 1000000};
    import_mesh a, b;
    int ra, rb;

    if (fz_skip_known(data, size))
        return -1;
    ra = import_checked(data, size, fz_self.hint, &y_up, &a);
    rb = import_checked(data, size, NULL, &z_up, &b);

    n_imports[0]++;
    n_imports[1]++;
    n_ok[0] += ra == 0;
    n_ok[1] += rb == 0;
    if (rb == 0) {
        FZ_CHECK(ra == 0 && a.ntris == b.ntris);
        for (size_t i = 0; i < (size_t)a.ntris * 9; i += 3)
            FZ_CHECK(b.tris[i] == a.tris[i] && b.tris[i + 1] == a.tris[i + 2] &&
                     b.tris[i + 2] == -a.tris[i + 1]);
    }
    import_mesh_free(&a);
    import_mesh_free(&b);
    return 0;
}

void fz_import_report(void)
{
    fprintf(stderr, "%s: %lu imports with hint %s, %lu succeeded; %lu without, %lu succeeded\n",
            fz_self.name, n_imports[0], fz_self.hint, n_ok[0], n_imports[1], n_ok[1]);
}
