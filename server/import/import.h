/*
 * import.h: turns an uploaded 3D model file into the triangles the server
 * keeps and their bounding box (the object's MBR, ECM version 1).
 *
 * Parsing is Assimp's (C API); this module decides which files reach it.
 * Only the formats in import_formats() are accepted, recognised by their
 * content, and each is pre-checked where Assimp 5.2.5 was found to crash,
 * hang, leak or allocate without bound on hostile input (see import.c and
 * each format's import_FORMAT.c). The file is read from memory only:
 * references to other files (OBJ mtllib, glTF buffer and image URIs) are
 * never opened.
 *
 * Every function here may be called from any thread. Assimp's parse step
 * is serialised internally (it keeps its last error in a global); the
 * checks before it and the walk after it run in parallel.
 */
#ifndef CVRE_IMPORT_H
#define CVRE_IMPORT_H

#include <stddef.h>
#include <stdint.h>

/* ---- limits (override with -D at build time) ---------------------------- */

/* Largest file accepted. 4M triangles of OBJ with normals and texture
 * coordinates (sponza: 84 bytes per triangle) is about 340 MB; the default
 * triangle limit refuses such a file anyway, and Assimp holds the file and
 * two or three parsed copies of it in memory while importing. Must fit
 * Assimp's unsigned int length. */
#ifndef IMPORT_MAX_BYTES
#define IMPORT_MAX_BYTES (256u * 1024u * 1024u)
#endif

/* Default for import_options.max_triangles. Ten times the largest test
 * scene (a city block, 400,020 triangles); the result is 36 bytes per
 * triangle (144 MB here), kept for the object's lifetime and voxelized on
 * every refinement, so a bigger upload is refused rather than stored. */
#ifndef IMPORT_MAX_TRIANGLES
#define IMPORT_MAX_TRIANGLES 4000000u
#endif

/* Assimp triangulates each polygon in time quadratic in its vertex count
 * (a 100,000-vertex OBJ face, 0.7 MB, took 56 s). Polygons over four
 * vertices may total at most this many squared vertices: one 10,000-vertex
 * polygon (0.6 s measured), or 100,000 32-gons. */
#ifndef IMPORT_MAX_POLYGON_WORK
#define IMPORT_MAX_POLYGON_WORK 100000000ull
#endif

/* Deepest node hierarchy accepted. Assimp's glTF reader recurses per
 * level and overflowed an 8 MiB stack on a 20,000-deep chain (a 300 KB
 * file); our walk recurses too (about 350 bytes a level, 90 KB here).
 * Real files nest a few dozen levels, skeletons included. */
#ifndef IMPORT_MAX_NODE_DEPTH
#define IMPORT_MAX_NODE_DEPTH 256
#endif

/* Farthest a vertex may lie from the model's origin, in metres after the
 * unit scale: ten times the largest world (--world-size 100 km). A vertex
 * at 1e38 m, finite as a float, overflowed to infinity once placed at a
 * scale of 1000 and gave everyone a box of infinities. */
#ifndef IMPORT_MAX_COORD
#define IMPORT_MAX_COORD 1e6
#endif

/* Deepest JSON nesting accepted in a GLB. Assimp's JSON parser (rapidjson)
 * recurses per level and overflowed an 8 MiB stack at 10^6 levels; glTF
 * documents nest about ten deep, extensions included. */
#ifndef IMPORT_MAX_JSON_DEPTH
#define IMPORT_MAX_JSON_DEPTH 64
#endif

/* Most bytes jansson may allocate parsing a GLB's JSON chunk. The JSON
 * describes the scene and bulk data lives in the binary chunk: large real
 * files have 10^5 values, which jansson keeps in about 10 MB. A chunk of
 * 16 MiB of empty arrays would take over 500 MB. */
#ifndef IMPORT_MAX_JSON_MEMORY
#define IMPORT_MAX_JSON_MEMORY (128u << 20)
#endif

/* Most nodes a GLB may expand to. Assimp makes one aiNode (over 1 KiB:
 * its name is a fixed 1 KiB string) per path from a scene root, so shared
 * children multiply: a 1 KB file of nodes listing the next one twice
 * exhausted 24 GB. glTF requires trees; this also bounds a node listed as
 * a root at every level of a chain (~110 MB at the limit). */
#ifndef IMPORT_MAX_GLB_NODES
#define IMPORT_MAX_GLB_NODES 100000u
#endif

/* Most accessor elements a GLB's mesh primitives may copy, counted once
 * per primitive that uses an accessor (Assimp copies it each time): 1,000
 * primitives sharing a 300,000-vertex accessor, a 3.6 MB file, took 52 s
 * and 17.6 GB. Each element takes at least a byte of the file unless it
 * is shared, and real meshes use about 0.2 per byte; the per-byte factor
 * leaves room for primitives sharing vertex data, as multi-material
 * exporters do. The absolute cap, twelve per triangle at the default
 * triangle limit (positions, normals, texture coordinates, indices),
 * bounds big files: Assimp spends up to ~60 bytes per element. */
#ifndef IMPORT_GLB_ELEMENTS_PER_BYTE
#define IMPORT_GLB_ELEMENTS_PER_BYTE 2u
#endif
#ifndef IMPORT_MAX_GLB_ELEMENTS
#define IMPORT_MAX_GLB_ELEMENTS (12ull * IMPORT_MAX_TRIANGLES)
#endif

/* Most named parts a text file may start: OBJ `o`, `g` and `usemtl`
 * statements, STL `solid` blocks. Assimp makes a mesh and a node per part
 * and looks OBJ names up linearly: 200,000 distinct object names took
 * 52 s, material names 54 s and 7 GB (36 KB each), empty STL solids 1 GB
 * from 6 MB. At this limit: under 0.4 s and 400 MB. Sponza has 71. */
#ifndef IMPORT_MAX_PARTS
#define IMPORT_MAX_PARTS 10000u
#endif

/* Most properties a PLY header may declare over all its elements. Real
 * files have a dozen (position, normal, colour, texture coordinates); the
 * pre-check keeps them in a fixed table. */
#ifndef IMPORT_MAX_PLY_PROPERTIES
#define IMPORT_MAX_PLY_PROPERTIES 256
#endif

/* ---- the interface ------------------------------------------------------ */

typedef struct import_options {
    int z_up;               /* the file is Z-up: (x,y,z) -> (x,z,-y), so +z becomes +y */
    float unit_scale;       /* multiplies every coordinate; > 0 and finite (0.01 for cm) */
    uint32_t max_triangles; /* refuse more than this (-EFBIG); >= 1 */
} import_options;

/* Y-up metres, the default triangle limit. */
#define IMPORT_OPTIONS_DEFAULT {0, 1.0f, IMPORT_MAX_TRIANGLES}

typedef struct import_mesh {
    float *tris;          /* 9 floats per triangle: x,y,z of its three vertices */
    uint32_t ntris;       /* >= 1 after a successful import */
    float min[3], max[3]; /* AABB of those vertices: the object's MBR */
} import_mesh;

/*
 * Parses the model file data[0..len) and fills *out with every triangle of
 * every mesh instance, each vertex taken through its node transforms into
 * model space, then rotated if opt->z_up, then scaled by opt->unit_scale.
 * Points and lines are dropped; polygons are triangulated; degenerate
 * triangles are kept, so counts match the file. glTF is Y-up metres by
 * definition, OBJ/STL/PLY carry no unit or axis: the caller says.
 *
 * hint is the file's extension ("obj", "STL", ".glb"), or NULL or "" if
 * unknown. The content decides the format: GLB, PLY and STL (binary or
 * ASCII) are recognised by their signatures and OBJ by its first
 * statement, whatever the hint says, so a misnamed file still imports.
 * Content with no signature is parsed as OBJ only when the hint says obj;
 * otherwise it is refused. A hint naming a format not in import_formats()
 * is refused. opt NULL means IMPORT_OPTIONS_DEFAULT.
 *
 * Returns 0 with *out owning a new array (free with import_mesh_free);
 * otherwise *out is zeroed and the return is -EINVAL (not a model, an
 * unsupported or unrecognised format, a parse error, no triangles, a
 * non-finite coordinate, a pre-check refused the file, bad arguments),
 * -EFBIG (more than opt->max_triangles triangles, or len over
 * IMPORT_MAX_BYTES) or -ENOMEM. err (may be NULL if errlen is 0) gets a
 * one-line reason for a person, empty on success.
 */
int import_model(const void *data, size_t len, const char *hint, const import_options *opt,
                 import_mesh *out, char *err, size_t errlen);

/* Does the one-time set-up that needs more than memory (seeding the JSON
 * parser's hash from /dev/urandom), so that import_model can then run in a
 * process that may only read, write and allocate. import_model calls it
 * too; calling it again does nothing. */
void import_prepare(void);

/* Frees m's triangles and zeroes it; a zeroed mesh may be freed again. */
void import_mesh_free(import_mesh *m);

/* The accepted extensions, space-separated ("obj stl ply glb"), for
 * --help and error messages. Static storage. */
const char *import_formats(void);

#endif
