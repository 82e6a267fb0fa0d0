/*
 * import.c: model files to triangles, through Assimp's C API: the entry
 * point, which format a file is, Assimp's call, and its scene walked into
 * triangles. Each format's signature and pre-check is in a file of its own
 * (import_obj.c, import_stl.c, import_ply.c, import_glb.c; importInt.h
 * lists them all).
 *
 * What Assimp 5.2.5 (Debian libassimp5) does with hostile input, found
 * under ASan, valgrind and fuzzing, and what the importer does about it;
 * each format's file says what its reader does:
 *
 * - It is built with assertions on (ASSIMP_BUILD_DEBUG): a zero-length
 *   buffer aborts the process. We refuse empty input first.
 * - Importing "from memory" still opens files on the local disk: an OBJ's
 *   `mtllib /etc/passwd`, a glTF buffer URI. A buffer URI turns the named
 *   file's bytes into vertices, which the server would keep and show; a
 *   FIFO would block. We hand Assimp our own aiFileIO that serves the
 *   upload and nothing else, so missing .mtl files and textures are simply
 *   absent.
 * - Any of its 48 importers can be reached: with no usable extension it
 *   asks each whether it wants the file, and for an extension claimed by
 *   two (glb) it asks everyone when both decline. Some crash or hang on
 *   small files (its own test models: an OpenGEX file segfaults, an OFF
 *   and an SMD file hang), COLLADA expands a 3 KB file of shared
 *   instance_node references into 14 GB, and without an extension a
 *   binary STL is taken for OBJ and a GLB for nothing. So we recognise
 *   the four formats we accept ourselves, always name one, and make sure
 *   its reader takes the file.
 * - Its readers leak their mesh (1.3-2.4 KB) whenever they throw on a
 *   malformed file, so the pre-checks refuse what makes them throw. That
 *   means reading the file as Assimp does (import_text.c): fuzzing found
 *   its readers ending lines at NUL and CR, taking "l1" for a statement,
 *   ".5" for no number and an STL vertex's numbers only from its own line;
 *   files a plain reading would take differently are refused.
 * - Triangulation is quadratic in polygon size: we bound the sum of squares
 *   before triangulating (IMPORT_MAX_POLYGON_WORK).
 * - Exceptions (std::bad_alloc included) are caught inside the C API and
 *   become a NULL scene. Its logger is a null logger unless one is
 *   attached; we attach none, so nothing reaches stderr.
 * - Each aiImportFile* call makes its own Importer, but the last error is a
 *   global std::string written inside the call: imports are serialised.
 *
 * These guards answer what was found, not everything Assimp might do:
 * cvre-import runs imports in a separate process with memory and time
 * limits to contain the rest (import_proc.h).
 */
#include "import.h"
#include "importInt.h"

#include <errno.h>
#include <float.h>
#include <limits.h>
#include <math.h>
#include <pthread.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include <assimp/cfileio.h>
#include <assimp/cimport.h>
#include <assimp/postprocess.h>
#include <assimp/scene.h>

#include "alloc.h"
#include "err.h"

_Static_assert(IMPORT_MAX_BYTES > 0 && IMPORT_MAX_BYTES <= UINT_MAX,
               "Assimp takes the length as unsigned int");
_Static_assert(IMPORT_MAX_TRIANGLES >= 1, "a model has at least one triangle");
_Static_assert(IMPORT_MAX_POLYGON_WORK >= 16, "quads must always pass");
_Static_assert(IMPORT_MAX_NODE_DEPTH >= 8 && IMPORT_MAX_NODE_DEPTH <= 4096,
               "deep enough for real files, shallow enough for a thread's stack");
_Static_assert(IMPORT_MAX_JSON_DEPTH >= 16 && IMPORT_MAX_JSON_DEPTH <= 1024,
               "deep enough for glTF, shallow enough for rapidjson's recursion");
_Static_assert(IMPORT_MAX_JSON_MEMORY >= (1u << 20), "room for real documents");
_Static_assert(IMPORT_MAX_GLB_NODES >= 1, "a scene has a node");
_Static_assert(IMPORT_GLB_ELEMENTS_PER_BYTE >= 1 && IMPORT_MAX_GLB_ELEMENTS >= 3,
               "an unshared triangle must pass");
_Static_assert(IMPORT_MAX_PARTS >= 1, "a file has a part");
_Static_assert(IMPORT_MAX_PLY_PROPERTIES >= 16 && IMPORT_MAX_PLY_PROPERTIES <= 4096,
               "a fixed table on the stack");

/* Files Assimp may have open at once through our aiFileIO. The existence
 * check, the size query and the read each open and close the upload, one
 * at a time in every format here; the rest is headroom. */
#define OPEN_MAX 4

/* Assimp keeps its last error in a global: one import at a time. */
static pthread_mutex_t assimp_lock = PTHREAD_MUTEX_INITIALIZER;

/* ---- the upload as Assimp's only file ----------------------------------- */

typedef struct memfile {
    struct aiFile f; /* first: Assimp hands this back */
    const char *data;
    size_t len, pos;
    int used;
} memfile;

typedef struct memfs {
    struct aiFileIO io; /* first, likewise */
    const char *name;   /* the one path that opens */
    const char *data;
    size_t len;
    memfile files[OPEN_MAX];
} memfs;

static size_t mem_read(struct aiFile *f, char *buf, size_t size, size_t count)
{
    memfile *m = (memfile *)(void *)f;
    size_t n;

    if (size == 0 || count == 0)
        return 0;
    n = (m->len - m->pos) / size;
    if (n > count)
        n = count;
    memcpy(buf, m->data + m->pos, n * size);
    m->pos += n * size;
    return n;
}

static size_t mem_write(struct aiFile *f, const char *buf, size_t size, size_t count)
{
    (void)f, (void)buf, (void)size, (void)count;
    return 0;
}

static size_t mem_tell(struct aiFile *f) { return ((memfile *)(void *)f)->pos; }

static size_t mem_size(struct aiFile *f) { return ((memfile *)(void *)f)->len; }

static void mem_flush(struct aiFile *f) { (void)f; }

/* Seeks like Assimp's own memory stream: from the end, offset counts back. */
static enum aiReturn mem_seek(struct aiFile *f, size_t off, enum aiOrigin origin)
{
    memfile *m = (memfile *)(void *)f;
    size_t base = origin == aiOrigin_SET ? 0 : origin == aiOrigin_CUR ? m->pos : m->len;

    if (origin == aiOrigin_END) {
        if (off > m->len)
            return aiReturn_FAILURE;
        m->pos = m->len - off;
        return aiReturn_SUCCESS;
    }
    if (off > m->len - base)
        return aiReturn_FAILURE;
    m->pos = base + off;
    return aiReturn_SUCCESS;
}

/* Opens the upload for reading; every other path, and any write, fails as
 * if the file did not exist (how Assimp treats a missing .mtl or texture). */
static struct aiFile *mem_open(struct aiFileIO *io, const char *path, const char *mode)
{
    memfs *fs = (memfs *)(void *)io;

    if (strcmp(path, fs->name) != 0 || strpbrk(mode, "wa+"))
        return NULL;
    for (int i = 0; i < OPEN_MAX; i++) {
        memfile *m = &fs->files[i];
        if (m->used)
            continue;
        memset(m, 0, sizeof *m);
        m->f.ReadProc = mem_read;
        m->f.WriteProc = mem_write;
        m->f.TellProc = mem_tell;
        m->f.FileSizeProc = mem_size;
        m->f.SeekProc = mem_seek;
        m->f.FlushProc = mem_flush;
        m->data = fs->data;
        m->len = fs->len;
        m->used = 1;
        return &m->f;
    }
    return NULL;
}

static void mem_close(struct aiFileIO *io, struct aiFile *f)
{
    (void)io;
    ((memfile *)(void *)f)->used = 0;
}

/* ---- the formats -------------------------------------------------------- */

/* In the order their signatures are tried: GLB and PLY open with a magic
 * word; a binary STL has a size that agrees with its count (tried before
 * an ASCII STL's "solid", which binary headers often start with); OBJ has
 * no signature but its first statement, so it comes last. */
static const import__format *const formats[] = {&import__glb, &import__ply, &import__stl, &import__obj};

const char *import_formats(void) { return "obj stl ply glb"; }

/* The format the content p[0..n) (n >= 1) shows, or NULL. */
static const import__format *sniff(const unsigned char *p, size_t n)
{
    for (size_t f = 0; f < sizeof formats / sizeof formats[0]; f++)
        if (formats[f]->sniff(p, n))
            return formats[f];
    return NULL;
}

/* The format the hint names: 0 with *f (NULL when there is no hint), or
 * -EINVAL when it names one not supported. */
static int hint_format(const char *hint, const import__format **f)
{
    *f = NULL;
    if (!hint || !*hint)
        return 0;
    if (*hint == '.')
        hint++;
    for (size_t k = 0; k < sizeof formats / sizeof formats[0]; k++)
        if (strlen(hint) == strlen(formats[k]->ext) &&
            import__starts_with((const unsigned char *)hint, strlen(hint), formats[k]->ext)) {
            *f = formats[k];
            return 0;
        }
    return -EINVAL;
}

/* ---- from Assimp's scene to triangles ----------------------------------- */

typedef struct walk {
    const struct aiScene *scene;
    const uint32_t *mesh_tris; /* triangles in each mesh */
    uint32_t max_tris;
    uint64_t ntris; /* counted, then emitted */
    float *out;     /* NULL while counting */
    int z_up;
    double scale;
    float min[3], max[3];
    char *err;
    size_t errlen;
} walk;

/* Counts each mesh's triangles into w->mesh_tris, checking the indices
 * they use. Polygons were triangulated and anything else (points, lines)
 * is skipped. Returns 0 or -EINVAL. */
static int count_meshes(const struct aiScene *sc, uint32_t *mesh_tris, char *err, size_t errlen)
{
    for (unsigned m = 0; m < sc->mNumMeshes; m++) {
        const struct aiMesh *me = sc->mMeshes[m];
        uint32_t t = 0;
        if (!me)
            return cvre_fail(err, errlen, -EINVAL, "mesh %u missing", m);
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            const struct aiFace *fa = &me->mFaces[f];
            if (fa->mNumIndices != 3)
                continue;
            if (!me->mVertices)
                return cvre_fail(err, errlen, -EINVAL, "mesh %u has faces but no positions", m);
            for (int k = 0; k < 3; k++)
                if (fa->mIndices[k] >= me->mNumVertices)
                    return cvre_fail(err, errlen, -EINVAL, "mesh %u: vertex index %u out of range", m,
                                fa->mIndices[k]);
            t++;
        }
        mesh_tris[m] = t;
    }
    return 0;
}

/* Sums, over polygons of more than four vertices (quads are split in
 * constant time), the square of their size: what triangulating costs. */
static int check_polygons(const struct aiScene *sc, char *err, size_t errlen)
{
    uint64_t work = 0;
    unsigned largest = 0;

    for (unsigned m = 0; m < sc->mNumMeshes; m++) {
        const struct aiMesh *me = sc->mMeshes[m];
        if (!me)
            continue;
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            unsigned k = me->mFaces[f].mNumIndices;
            if (k <= 4)
                continue;
            if (k > largest)
                largest = k;
            work += (uint64_t)k * k;
            if (work > IMPORT_MAX_POLYGON_WORK)
                return cvre_fail(err, errlen, -EINVAL,
                            "polygons too large to triangulate (largest so far %u vertices; "
                            "their squared sizes may total %llu)",
                            largest, (unsigned long long)IMPORT_MAX_POLYGON_WORK);
        }
    }
    return 0;
}

/* r = a * b, 4x4 row-major. */
static void mat_mul(double r[16], const double a[16], const double b[16])
{
    for (int i = 0; i < 4; i++)
        for (int k = 0; k < 4; k++)
            r[4 * i + k] = a[4 * i] * b[k] + a[4 * i + 1] * b[4 + k] + a[4 * i + 2] * b[8 + k] +
                           a[4 * i + 3] * b[12 + k];
}

/* Writes one vertex: node transform m, then the up-axis, then the scale. */
static int emit_vertex(walk *w, const double m[16], const struct aiVector3D *v, float *o)
{
    double x = v->x, y = v->y, z = v->z;
    double p[3] = {m[0] * x + m[1] * y + m[2] * z + m[3], m[4] * x + m[5] * y + m[6] * z + m[7],
                   m[8] * x + m[9] * y + m[10] * z + m[11]};

    if (w->z_up) {
        double t = p[1];
        p[1] = p[2];
        p[2] = -t;
    }
    for (int k = 0; k < 3; k++) {
        double s = p[k] * w->scale;
        /* also false for NaN; checked before the conversion, which
         * would be undefined out of range */
        if (!(fabs(s) <= FLT_MAX))
            return cvre_fail(w->err, w->errlen, -EINVAL,
                        "coordinate not a finite float in triangle %llu",
                        (unsigned long long)w->ntris + 1);
        if (fabs(s) > IMPORT_MAX_COORD)
            return cvre_fail(w->err, w->errlen, -EINVAL,
                        "coordinate %.3g m in triangle %llu is beyond %.0f km of the model's origin", s,
                        (unsigned long long)w->ntris + 1, IMPORT_MAX_COORD / 1000.0);
        o[k] = (float)s;
        if (o[k] < w->min[k])
            w->min[k] = o[k];
        if (o[k] > w->max[k])
            w->max[k] = o[k];
    }
    return 0;
}

/*
 * Visits node and its subtree with parent's accumulated transform: counts
 * the triangles of every mesh instance (w->out NULL) or writes them.
 * Counting stops as soon as the total passes w->max_tris. Returns 0,
 * -EINVAL or -EFBIG.
 */
static int visit(walk *w, const struct aiNode *node, const double parent[16], unsigned depth)
{
    const struct aiMatrix4x4 *t = &node->mTransformation;
    const double local[16] = {t->a1, t->a2, t->a3, t->a4, t->b1, t->b2, t->b3, t->b4,
                              t->c1, t->c2, t->c3, t->c4, t->d1, t->d2, t->d3, t->d4};
    double m[16];
    int rc;

    if (depth > IMPORT_MAX_NODE_DEPTH)
        return cvre_fail(w->err, w->errlen, -EINVAL, "node hierarchy deeper than %d",
                    IMPORT_MAX_NODE_DEPTH);
    mat_mul(m, parent, local);
    for (unsigned i = 0; i < node->mNumMeshes; i++) {
        unsigned mi = node->mMeshes[i];
        const struct aiMesh *me;
        if (mi >= w->scene->mNumMeshes)
            return cvre_fail(w->err, w->errlen, -EINVAL, "node refers to missing mesh %u", mi);
        if (!w->out) {
            w->ntris += w->mesh_tris[mi];
            if (w->ntris > w->max_tris)
                return cvre_fail(w->err, w->errlen, -EFBIG, "more than %u triangles", w->max_tris);
            continue;
        }
        me = w->scene->mMeshes[mi];
        for (unsigned f = 0; f < me->mNumFaces; f++) {
            const struct aiFace *fa = &me->mFaces[f];
            float *o = w->out + 9 * w->ntris;
            if (fa->mNumIndices != 3)
                continue;
            for (int k = 0; k < 3; k++)
                if ((rc = emit_vertex(w, m, &me->mVertices[fa->mIndices[k]], o + 3 * k)) != 0)
                    return rc;
            w->ntris++;
        }
    }
    for (unsigned i = 0; i < node->mNumChildren; i++) {
        if (!node->mChildren[i])
            return cvre_fail(w->err, w->errlen, -EINVAL, "node child missing");
        if ((rc = visit(w, node->mChildren[i], m, depth + 1)) != 0)
            return rc;
    }
    return 0;
}

/* Triangles of every mesh instance into out. Returns 0, -EINVAL, -EFBIG
 * or -ENOMEM. */
static int collect(const struct aiScene *sc, const import_options *opt, import_mesh *out, char *err,
                   size_t errlen)
{
    static const double identity[16] = {1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 1};
    walk w;
    uint32_t *mesh_tris;
    int rc;

    if (!sc->mRootNode)
        return cvre_fail(err, errlen, -EINVAL, "no scene graph");
    mesh_tris = cvre_calloc(sc->mNumMeshes, sizeof *mesh_tris);
    if (!mesh_tris)
        return cvre_fail(err, errlen, -ENOMEM, "out of memory");
    memset(&w, 0, sizeof w);
    w.scene = sc;
    w.mesh_tris = mesh_tris;
    w.max_tris = opt->max_triangles;
    w.z_up = opt->z_up;
    w.scale = opt->unit_scale;
    w.err = err;
    w.errlen = errlen;
    if ((rc = count_meshes(sc, mesh_tris, err, errlen)) != 0 ||
        (rc = visit(&w, sc->mRootNode, identity, 0)) != 0)
        goto cleanup;
    if (w.ntris == 0) {
        rc = cvre_fail(err, errlen, -EINVAL, "the file has no triangles");
        goto cleanup;
    }
    /* GCOVR_EXCL_START: w.ntris is at most max_triangles, a uint32_t, so
     * this holds only where size_t has 32 bits */
    if (w.ntris > SIZE_MAX / (9 * sizeof(float))) {
        rc = cvre_fail(err, errlen, -ENOMEM, "out of memory");
        goto cleanup;
    }
    /* GCOVR_EXCL_STOP */
    out->tris = cvre_malloc((size_t)w.ntris * 9 * sizeof(float));
    if (!out->tris) {
        rc = cvre_fail(err, errlen, -ENOMEM, "out of memory for %llu triangles",
                  (unsigned long long)w.ntris);
        goto cleanup;
    }
    w.out = out->tris;
    w.ntris = 0;
    for (int k = 0; k < 3; k++) {
        w.min[k] = FLT_MAX;
        w.max[k] = -FLT_MAX;
    }
    if ((rc = visit(&w, sc->mRootNode, identity, 0)) != 0) {
        import_mesh_free(out);
        goto cleanup;
    }
    out->ntris = (uint32_t)w.ntris;
    memcpy(out->min, w.min, sizeof w.min);
    memcpy(out->max, w.max, sizeof w.max);
cleanup:
    free(mesh_tris);
    return rc;
}

/* ---- the entry points --------------------------------------------------- */

static int check_options(const import_options *o, char *err, size_t errlen)
{
    if (!(o->unit_scale > 0.0f) || !isfinite(o->unit_scale))
        return cvre_fail(err, errlen, -EINVAL, "unit_scale must be positive and finite");
    if (o->max_triangles == 0)
        return cvre_fail(err, errlen, -EINVAL, "max_triangles must be at least 1");
    return 0;
}

void import_mesh_free(import_mesh *m)
{
    free(m->tris);
    memset(m, 0, sizeof *m);
}

int import_model(const void *data, size_t len, const char *hint, const import_options *opt,
                 import_mesh *out, char *err, size_t errlen)
{
    static const import_options defaults = IMPORT_OPTIONS_DEFAULT;
    const unsigned char *p = data;
    const struct aiScene *sc;
    const import__format *fmt, *hinted;
    memfs fs;
    char name[16];
    int rc;

    if (errlen)
        err[0] = 0;
    if (!out)
        return cvre_fail(err, errlen, -EINVAL, "no output mesh");
    memset(out, 0, sizeof *out);
    if (!opt)
        opt = &defaults;
    if ((rc = check_options(opt, err, errlen)) != 0)
        return rc;
    if (!data || len == 0)
        return cvre_fail(err, errlen, -EINVAL, "empty file");
    if (len > IMPORT_MAX_BYTES)
        return cvre_fail(err, errlen, -EFBIG, "file of %zu bytes is over the %u-byte limit", len,
                    (unsigned)IMPORT_MAX_BYTES);
    if (hint_format(hint, &hinted) != 0) {
        rc = cvre_fail(err, errlen, -EINVAL, "unsupported format \"%.16s\" (supported: %s)", hint,
                       import_formats());
        import__printable(err, errlen); /* the hint is the client's */
        return rc;
    }
    fmt = sniff(p, len);
    if (!fmt && hinted == &import__obj)
        fmt = &import__obj;
    if (!fmt)
        return hinted ? cvre_fail(err, errlen, -EINVAL, "not a valid %s file", hinted->name)
                      : cvre_fail(err, errlen, -EINVAL, "unrecognised format (supported: %s)",
                                  import_formats());
    if ((rc = fmt->check(p, len, err, errlen)) != 0)
        return rc;

    snprintf(name, sizeof name, "upload.%s", fmt->ext);
    memset(&fs, 0, sizeof fs);
    fs.io.OpenProc = mem_open;
    fs.io.CloseProc = mem_close;
    fs.name = name;
    fs.data = data;
    fs.len = len;
    pthread_mutex_lock(&assimp_lock);
    sc = aiImportFileEx(name, 0, &fs.io);
    if (!sc) {
        const char *why = aiGetErrorString();
        rc = strstr(why, "bad_alloc") ? -ENOMEM : -EINVAL;
        cvre_fail(err, errlen, rc, "%s parse error: %s", fmt->name, *why ? why : "(no reason given)");
        import__printable(err, errlen); /* Assimp may quote the file */
    }
    pthread_mutex_unlock(&assimp_lock);
    if (!sc)
        return rc;
    if ((rc = check_polygons(sc, err, errlen)) != 0) {
        aiReleaseImport(sc);
        return rc;
    }
    /* On failure this releases the scene. */
    sc = aiApplyPostProcessing(sc, aiProcess_Triangulate);
    /* GCOVR_EXCL_START: Assimp's triangulation throws nothing but
     * std::bad_alloc (caught inside, the scene freed), so only running out
     * of memory there, which no test can cause at will, gets here */
    if (!sc)
        return cvre_fail(err, errlen, -EINVAL, "%s: triangulation failed", fmt->name);
    /* GCOVR_EXCL_STOP */
    rc = collect(sc, opt, out, err, errlen);
    aiReleaseImport(sc);
    return rc;
}
