/*
 * import_proc.h: import_model in a separate, limited process.
 *
 * import_isolated starts the helper cvre-import (server/import/import_main.c)
 * for one upload, hands it the file on a pipe and reads the triangles back
 * in the length-checked form of import_pipe.h, checking them as it would
 * check a peer on the network. The helper runs under an address-space and
 * CPU limit and a seccomp filter, so a parser that crashes, spins or
 * allocates without end ends that process only; the caller gets an error.
 */
#ifndef CVRE_IMPORT_PROC_H
#define CVRE_IMPORT_PROC_H

#include <stddef.h>
#include <stdint.h>

#include "import.h"

/* Defaults for the helper's limits. Sponza (262,267 triangles) imports in
 * about a second and 200 MB; the 4M-triangle limit needs about 2 GB in
 * Assimp plus 150 MB of answer. The wall-clock deadline covers a helper
 * that blocks without spending CPU. */
#ifndef IMPORT_PROC_MEMORY_MB
#define IMPORT_PROC_MEMORY_MB 4096u
#endif
#ifndef IMPORT_PROC_CPU_SECONDS
#define IMPORT_PROC_CPU_SECONDS 30u
#endif
#define IMPORT_PROC_WALL_SECONDS(cpu) (2u * (cpu) + 10u)
_Static_assert(IMPORT_PROC_MEMORY_MB >= 256u, "Assimp and the libraries need room to load");
_Static_assert(IMPORT_PROC_CPU_SECONDS >= 1u, "a model takes some time");

typedef struct import_proc {
    const char *helper;      /* path of cvre-import */
    uint32_t memory_mb;      /* the helper's address space */
    uint32_t cpu_seconds;    /* the helper's CPU time */
} import_proc;

/* The helper's default path: cvre-import beside the running executable
 * (or "cvre-import" to be found on PATH if that cannot be told). Static
 * storage. */
const char *import_proc_default_helper(void);

/*
 * As import_model (same arguments, same results on success and for a
 * refused model: -EINVAL, -EFBIG, with the helper's message), run in the
 * helper. Besides: -EFBIG "too large" when the helper ran out of memory or
 * answered more than opt->max_triangles allows; -ETIMEDOUT when it passed
 * its CPU limit or the wall-clock deadline; -ECHILD when it crashed
 * (a signal, including the seccomp filter's) or exited without answering;
 * -EPROTO when its answer was malformed; -ENOMEM or another -errno when the
 * helper could not be started or fed. err always says which, on one line.
 * Safe to call from any thread; each call runs its own helper.
 */
int import_isolated(const import_proc *p, const void *data, size_t len, const char *hint,
                    const import_options *opt, import_mesh *out, char *err, size_t errlen);

#endif
