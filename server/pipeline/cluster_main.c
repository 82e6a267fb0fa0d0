/*
 * cvre-cluster: the offline clustering job. For each object in the world it
 * reads the collisions against the object's current ECM version, in
 * object-local coordinates, clusters them with DBSCAN (dbscan.h) and writes
 * a run record and one row per cluster, each naming the ECM box nearest its
 * centroid (where it presses). With --apply it then refines each object
 * with clusters (server/pipeline/apply.h) and writes its next ECM version,
 * which a running server picks up and publishes, if the judge finds it
 * better (else a rejected candidate). Safe beside a running server: it
 * reads in one snapshot (WAL) and writes in short transactions.
 */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

#include "alloc.h"
#include "apply.h"
#include "db.h"
#include "dbscan.h"
#include "find.h"
#include "num.h"
#include "record.h"
#include "timefmt.h"

enum { EXIT_OK = 0, EXIT_USAGE = 2, EXIT_DB = 3, EXIT_INTERNAL = 4 };

/* Objects one run may name with --object. */
#define MAX_OBJECT_FLAGS 256

static const char usage[] =
    "usage: cvre-cluster [options]\n"
    "\n"
    "Finds where users keep colliding with each object (DBSCAN over the collision\n"
    "log of the object's current collision map, in object-local coordinates) and\n"
    "records the clusters and the boxes they press on.\n"
    "\n"
    "  --db FILE          the database (default cvre.db)\n"
    "  --eps M            neighbourhood radius in metres, > 0 (default 0.5)\n"
    "  --min-points N     collisions within eps to make a core point, >= 1 (default 10)\n"
    "  --min-users N      distinct users a cluster needs, >= 1 (default 3)\n"
    "  --object ID        only this object (repeatable)\n"
    "  --since T, --until T  only collisions in this window: Unix seconds, or ISO 8601\n"
    "                     as cvre-admin prints and takes it (2026-12-01T17:40:00Z,\n"
    "                     2026-12-01T17:40:00.5, 2026-12-01 18:40+01:00; UTC\n"
    "                     without a zone); both ends included\n"
    "  --apply            refine every object with clusters and write its next\n"
    "                     collision map version (a running server publishes it) if\n"
    "                     a judge finds it better: the avatar walked from the\n"
    "                     clusters' collisions meets fewer boxes where no triangle\n"
    "                     is, and enters no geometry; otherwise it is stored as a\n"
    "                     rejected candidate (cvre-admin versions), and the same\n"
    "                     clusters are not refined again\n"
    "  --depth D          with --apply: grid of 2^D cells per axis of a box, 2..8 (default 7)\n"
    "  --max-boxes N      with --apply: most boxes per object, 1..1024 (default 64)\n"
    "  --max-empty F      with --apply: share of a merged box that may be empty, 0..1\n"
    "                     (default 0.25)\n"
    "  --threads N        most threads the clustering and each refinement run on,\n"
    "                     0..16; 0: one per CPU (default 0)\n"
    "  --json             print the result as one JSON object\n"
    "  --help, --version\n"
    "\n"
    "Exit codes: 0 done (clusters or not: see the summary), 2 bad arguments,\n"
    "3 database missing, of another schema version or unusable, 4 internal error\n"
    "or an object that could not be refined (the others were).\n";

typedef struct object_row {
    int64_t id;
    uint32_t version;
    float (*boxes)[6];
    uint32_t nboxes;
    int outcome;         /* ecm_apply's; 1: not refined (no clusters, or no --apply) */
    ecm_applied applied; /* with --apply */
} object_row;

/* The objects a round refines, for its callback (refined). */
typedef struct job_round {
    object_row *objs;
    size_t nobjs, at; /* found follows objs' order: the next object is at or after at */
    const char *path;
    int refused;
} job_round;

/* What became of one object (ecm_round_fn): kept for the report; a refusal
 * is counted and told, a failing store ends the round (1). */
static int refined(void *ctx, const cluster_found *f, uint32_t n, int rc, const ecm_applied *a, const char *err)
{
    (void)n;
    job_round *j = ctx;
    while (j->at < j->nobjs && j->objs[j->at].id != f[0].object_id)
        j->at++;
    if (j->at == j->nobjs) /* cannot happen: every cluster is of an object read */
        return 1;
    j->objs[j->at].outcome = rc;
    j->objs[j->at].applied = *a;
    if (rc == -EINVAL) {
        fprintf(stderr, "cvre-cluster: %s; not refined\n", err);
        j->refused++;
    } else if (rc < 0 && rc != -ESTALE) {
        fprintf(stderr, "cvre-cluster: %s: %s\n", j->path, err);
        return 1;
    }
    return 0;
}

static int fail_usage(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
static int fail_usage(const char *fmt, ...)
{
    va_list ap;
    va_start(ap, fmt);
    fprintf(stderr, "cvre-cluster: ");
    vfprintf(stderr, fmt, ap);
    fprintf(stderr, "; try --help\n");
    va_end(ap);
    return EXIT_USAGE;
}

int main(int argc, char **argv)
{
    enum { O_DB = 256, O_EPS, O_MINP, O_MINU, O_OBJ, O_SINCE, O_UNTIL, O_JSON, O_HELP, O_VERSION, O_APPLY, O_DEPTH,
           O_BOXES, O_EMPTY, O_THREADS };
    static const struct option opts[] = {
        {"db", required_argument, 0, O_DB},         {"eps", required_argument, 0, O_EPS},
        {"min-points", required_argument, 0, O_MINP}, {"min-users", required_argument, 0, O_MINU},
        {"object", required_argument, 0, O_OBJ},    {"since", required_argument, 0, O_SINCE},
        {"until", required_argument, 0, O_UNTIL},   {"json", no_argument, 0, O_JSON},
        {"help", no_argument, 0, O_HELP},           {"version", no_argument, 0, O_VERSION},
        {"apply", no_argument, 0, O_APPLY},         {"depth", required_argument, 0, O_DEPTH},
        {"max-boxes", required_argument, 0, O_BOXES}, {"max-empty", required_argument, 0, O_EMPTY},
        {"threads", required_argument, 0, O_THREADS}, {0, 0, 0, 0}};
    const char *path = "cvre.db";
    dbscan_params prm = {.eps = CLUSTER_EPS_DEFAULT, .min_points = CLUSTER_MIN_POINTS_DEFAULT,
                         .min_users = CLUSTER_MIN_USERS_DEFAULT, .threads = 0};
    ecm_params ep;
    ecm_params_default(&ep);
    int apply = 0;
    double since = -INFINITY, until = INFINITY;
    int json = 0, has_since = 0, has_until = 0, o;
    int64_t only[MAX_OBJECT_FLAGS];
    int nonly = 0;
    cvre_alloc_keep_freed(); /* it refines (alloc.h) */
    while ((o = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        switch (o) {
        case O_DB: path = optarg; break;
        case O_EPS:
            if (num_parse_real(optarg, 0, 1e6, &prm.eps) < 0 || prm.eps == 0 || prm.eps == 1e6)
                return fail_usage("--eps wants a distance in metres above 0, not \"%s\"", optarg);
            break;
        case O_MINP:
        case O_MINU: {
            long long v;
            if (num_parse_int(optarg, 1, 1000000, &v) < 0)
                return fail_usage("--%s wants a whole number from 1, not \"%s\"",
                                  o == O_MINP ? "min-points" : "min-users", optarg);
            *(o == O_MINP ? &prm.min_points : &prm.min_users) = (uint32_t)v;
            break;
        }
        case O_OBJ: {
            long long v;
            if (num_parse_int(optarg, 1, INT64_MAX, &v) < 0)
                return fail_usage("--object wants an object id, not \"%s\"", optarg);
            if (nonly == MAX_OBJECT_FLAGS)
                return fail_usage("too many --object flags (%s)", "256 at most");
            only[nonly++] = v;
            break;
        }
        case O_SINCE:
        case O_UNTIL:
            if (timefmt_parse(optarg, o == O_SINCE ? &since : &until) < 0)
                return fail_usage("a time is Unix seconds or ISO 8601 (2026-12-01T17:40:00Z, UTC without a zone), "
                                  "not \"%s\"", optarg);
            *(o == O_SINCE ? &has_since : &has_until) = 1;
            break;
        case O_JSON: json = 1; break;
        case O_APPLY: apply = 1; break;
        case O_DEPTH:
        case O_BOXES: {
            long long v;
            long lo = o == O_DEPTH ? ECM_DEPTH_MIN : 1, hi = o == O_DEPTH ? ECM_DEPTH_MAX : ECM_MAX_BOXES_LIMIT;
            if (num_parse_int(optarg, lo, hi, &v) < 0)
                return fail_usage("--%s wants a whole number from %ld to %ld, not \"%s\"",
                                  o == O_DEPTH ? "depth" : "max-boxes", lo, hi, optarg);
            *(o == O_DEPTH ? &ep.depth : &ep.max_boxes) = (uint32_t)v;
            break;
        }
        case O_EMPTY:
            if (num_parse_real(optarg, 0, 1, &ep.max_empty) < 0)
                return fail_usage("--max-empty wants a share from 0 to 1, not \"%s\"", optarg);
            break;
        case O_THREADS: {
            long long v;
            if (num_parse_int(optarg, 0, VOXEL_MAX_THREADS, &v) < 0)
                return fail_usage("--threads wants a whole number from 0 to %u, not \"%s\"", VOXEL_MAX_THREADS, optarg);
            prm.threads = ep.threads = (unsigned)v;
            break;
        }
        case O_HELP: fputs(usage, stdout); return EXIT_OK;
        case O_VERSION: printf("cvre-cluster %s\n", CVRE_VERSION); return EXIT_OK;
        default: fputs("cvre-cluster: try --help\n", stderr); return EXIT_USAGE;
        }
    }
    if (optind < argc)
        return fail_usage("unexpected argument \"%s\"", argv[optind]);
    if (access(path, F_OK) != 0) {
        fprintf(stderr, "cvre-cluster: %s: %s\n", path, strerror(errno));
        return EXIT_DB;
    }
    char err[512];
    /* The read-only open checks the schema version exactly; the job never
     * migrates a database (the server does). */
    db *check = db_open(path, DB_READONLY, err, sizeof err);
    if (!check) {
        fprintf(stderr, "cvre-cluster: %s\n", err);
        return EXIT_DB;
    }
    db_close(check);
    db *d = db_open(path, DB_READWRITE, err, sizeof err);
    if (!d) {
        fprintf(stderr, "cvre-cluster: %s\n", err);
        return EXIT_DB;
    }
    sqlite3 *sql = db_sqlite(d);
    double started = db_now();
    int rc = EXIT_INTERNAL;
    object_row *objs = NULL;
    size_t nobjs = 0;
    sqlite3_stmt *st = NULL;
    object_points pt = {0};
    uint64_t total_points = 0;
    int64_t run_id = 0;
    cluster_found *found = NULL;
    size_t nfound = 0;
    int refused = 0;

    /* One read snapshot for everything read. */
    if (sqlite3_exec(sql, "BEGIN", NULL, NULL, NULL) != SQLITE_OK)
        goto db_fail;
    if (sqlite3_prepare_v2(sql,
                           "SELECT o.id, o.ecm_version, b.min_x, b.min_y, b.min_z, b.max_x, b.max_y, b.max_z "
                           "FROM objects o JOIN ecm_boxes b ON b.object_id = o.id AND b.version = o.ecm_version "
                           "WHERE o.removed_at IS NULL ORDER BY o.id, b.box_index",
                           -1, &st, NULL) != SQLITE_OK)
        goto db_fail;
    while ((o = sqlite3_step(st)) == SQLITE_ROW) {
        int64_t id = sqlite3_column_int64(st, 0);
        int wanted = nonly == 0;
        for (int i = 0; i < nonly; i++)
            wanted |= only[i] == id;
        if (!wanted)
            continue;
        if (!nobjs || objs[nobjs - 1].id != id) {
            objs = cvre_xrealloc(objs, (nobjs + 1) * sizeof *objs);
            objs[nobjs++] = (object_row){.id = id, .version = (uint32_t)sqlite3_column_int64(st, 1), .outcome = 1};
        }
        object_row *r = &objs[nobjs - 1];
        r->boxes = cvre_xrealloc(r->boxes, (r->nboxes + 1) * sizeof *r->boxes);
        for (int k = 0; k < 6; k++)
            r->boxes[r->nboxes][k] = (float)sqlite3_column_double(st, 2 + k);
        r->nboxes++;
    }
    if (o != SQLITE_DONE)
        goto db_fail;
    sqlite3_finalize(st);
    st = NULL;
    for (int i = 0; i < nonly; i++) {
        int present = 0;
        for (size_t k = 0; k < nobjs; k++)
            present |= objs[k].id == only[i];
        if (!present)
            fprintf(stderr, "cvre-cluster: no object %lld in the world; skipped\n", (long long)only[i]);
    }

    /* The collision rows of each object's current version, read in id order.
     * Results are written after the read snapshot ends. */
    if (sqlite3_prepare_v2(sql,
                           "SELECT local_x, local_y, local_z, coalesce(user_id, -session_id) FROM collisions "
                           "WHERE object_id = ?1 AND ecm_version = ?2 AND at >= ?3 AND at <= ?4 ORDER BY id",
                           -1, &st, NULL) != SQLITE_OK)
        goto db_fail;
    int tty = isatty(STDERR_FILENO) && !json;
    for (size_t i = 0; i < nobjs; i++) {
        pt.n = 0;
        sqlite3_bind_int64(st, 1, objs[i].id);
        sqlite3_bind_int64(st, 2, objs[i].version);
        sqlite3_bind_double(st, 3, has_since ? since : -1e300);
        sqlite3_bind_double(st, 4, has_until ? until : 1e300);
        while ((o = sqlite3_step(st)) == SQLITE_ROW) {
            float xyz[3] = {(float)sqlite3_column_double(st, 0), (float)sqlite3_column_double(st, 1),
                            (float)sqlite3_column_double(st, 2)};
            object_points_add(&pt, xyz, (uint32_t)sqlite3_column_int64(st, 3));
        }
        sqlite3_reset(st);
        if (o != SQLITE_DONE)
            goto db_fail;
        total_points += pt.n;
        int drc = cluster_find(&pt, &prm, objs[i].id, objs[i].version, (const float(*)[6])objs[i].boxes,
                               objs[i].nboxes, &found, &nfound);
        if (drc < 0) {
            fprintf(stderr, "cvre-cluster: object %lld: clustering failed: %s\n", (long long)objs[i].id,
                    strerror(-drc));
            goto done;
        }
        if (tty)
            fprintf(stderr, "\rcvre-cluster: %zu/%zu objects, %llu collisions, %zu clusters", i + 1, nobjs,
                    (unsigned long long)total_points, nfound);
    }
    if (tty)
        fputc('\n', stderr);
    sqlite3_finalize(st);
    st = NULL;
    if (sqlite3_exec(sql, "COMMIT", NULL, NULL, NULL) != SQLITE_OK)
        goto db_fail;
    cluster_run run = {.started = started, .finished = db_now(), .params = prm, .has_since = has_since,
                       .has_until = has_until, .since = since, .until = until, .objects = nobjs,
                       .points = total_points};
    /* The run recorded; with --apply each object its clusters name refined,
     * judged and stored (apply.h), as the online loop does. */
    job_round jr = {.objs = objs, .nobjs = nobjs, .path = path};
    int round = ecm_apply_round(d, &ep, &run, found, nfound, apply, refined, &jr, &run_id, err, sizeof err);
    if (round != 0) {
        if (round < 0)
            fprintf(stderr, "cvre-cluster: %s: %s\n", path, err);
        rc = EXIT_DB;
        goto done;
    }
    refused = jr.refused;
    uint64_t problem_boxes = cluster_problem_boxes(found, nfound);

    if (json) {
        printf("{\"run\":%lld,\"objects\":%zu,\"points\":%llu,\"clusters\":[", (long long)run_id, nobjs,
               (unsigned long long)total_points);
        for (size_t k = 0; k < nfound; k++) {
            const cluster_found *f = &found[k];
            printf("%s{\"object\":%lld,\"ecm_version\":%u,\"cluster\":%u,\"points\":%u,\"users\":%u,"
                   "\"centroid\":[%.4f,%.4f,%.4f],\"min\":[%.4f,%.4f,%.4f],\"max\":[%.4f,%.4f,%.4f],\"box\":%u}",
                   k ? "," : "", (long long)f->object_id, f->ecm_version, f->cluster_id, f->c.points, f->c.users,
                   (double)f->c.centroid[0], (double)f->c.centroid[1], (double)f->c.centroid[2],
                   (double)f->c.min[0], (double)f->c.min[1], (double)f->c.min[2], (double)f->c.max[0],
                   (double)f->c.max[1], (double)f->c.max[2], f->box);
        }
        printf("],\"problem_boxes\":%llu,\"refined\":[", (unsigned long long)problem_boxes);
        int first = 1;
        for (size_t i = 0; i < nobjs; i++) {
            if (!apply || objs[i].outcome > 0)
                continue;
            const ecm_applied *a = &objs[i].applied;
            const judge_result *j = &a->judge;
            printf("%s{\"object\":%lld,\"from\":%u,\"outcome\":\"%s\",\"version\":%u,\"candidate\":%u,"
                   "\"boxes_before\":%u,\"boxes_after\":%u,\"capped\":%u,\"apart_over\":%u,\"voxel_ms\":%.3f,"
                   "\"divide_ms\":%.3f,"
                   "\"total_ms\":%.3f,\"judge\":{\"better\":%s,\"samples\":%u,\"moves\":%llu,"
                   "\"phantom_old\":%llu,\"phantom_new\":%llu,\"opened_old\":%llu,\"opened_new\":%llu,"
                   "\"ms\":%.3f}}",
                   first ? "" : ",", (long long)objs[i].id, objs[i].version,
                   objs[i].outcome == -EINVAL   ? "refused"
                   : objs[i].outcome == -ESTALE ? "stale"
                   : a->version            ? "written"
                   : a->judged_before      ? "rejected before"
                   : a->candidate          ? "rejected"
                   : a->no_gain            ? "nothing to gain"
                                           : "unchanged",
                   a->version, a->candidate, a->boxes_before, a->boxes_after, a->stats.capped, a->stats.apart_over,
                   a->stats.voxel_ms,
                   a->stats.divide_ms, a->total_ms, j->better ? "true" : "false", j->samples,
                   (unsigned long long)j->moves, (unsigned long long)j->phantom_old,
                   (unsigned long long)j->phantom_new, (unsigned long long)j->opened_old,
                   (unsigned long long)j->opened_new, j->ms);
            first = 0;
        }
        printf("]}\n");
    } else {
        printf("run %lld: %zu objects, %llu collisions, %zu clusters naming %llu boxes "
               "(eps %g m, min points %u, min users %u)\n",
               (long long)run_id, nobjs, (unsigned long long)total_points, nfound,
               (unsigned long long)problem_boxes, prm.eps, prm.min_points, prm.min_users);
        for (size_t k = 0; k < nfound; k++) {
            const cluster_found *f = &found[k];
            printf("  object %lld v%u cluster %u: %u collisions by %u users around (%.2f, %.2f, %.2f) -> box %u\n",
                   (long long)f->object_id, f->ecm_version, f->cluster_id, f->c.points, f->c.users,
                   (double)f->c.centroid[0], (double)f->c.centroid[1], (double)f->c.centroid[2], f->box);
        }
        for (size_t i = 0; apply && i < nobjs; i++) {
            const ecm_applied *a = &objs[i].applied;
            char figures[160];
            ecm_judge_line(&a->judge, figures, sizeof figures);
            if (objs[i].outcome == 0 && a->version)
                printf("  object %lld: v%u -> v%u, %u -> %u boxes (%.1f ms; %s)\n", (long long)objs[i].id,
                       objs[i].version, a->version, a->boxes_before, a->boxes_after, a->total_ms, figures);
            else if (objs[i].outcome == 0 && a->judged_before)
                printf("  object %lld: v%u unchanged: its clusters are those of candidate %u, rejected before\n",
                       (long long)objs[i].id, objs[i].version, a->candidate);
            else if (objs[i].outcome == 0 && a->candidate)
                printf("  object %lld: v%u kept: the refined map (%u -> %u boxes) is no better, stored as candidate "
                       "%u (%s)\n",
                       (long long)objs[i].id, objs[i].version, a->boxes_before, a->boxes_after, a->candidate,
                       figures);
            else if (objs[i].outcome == 0 && a->no_gain) {
                char why[160];
                ecm_no_gain_line(a, why, sizeof why);
                printf("  object %lld: v%u kept, not refined: %s (%s)\n", (long long)objs[i].id, objs[i].version, why,
                       figures);
            } else if (objs[i].outcome == 0) {
                char why[160];
                ecm_unchanged_line(a, why, sizeof why);
                printf("  object %lld: v%u unchanged: %s\n", (long long)objs[i].id, objs[i].version, why);
            }
            else if (objs[i].outcome == -ESTALE)
                printf("  object %lld: changed meanwhile; not refined\n", (long long)objs[i].id);
        }
    }
    if (refused) {
        rc = EXIT_INTERNAL;
        goto done;
    }
    rc = EXIT_OK;
    goto done;
db_fail:
    fprintf(stderr, "cvre-cluster: %s: %s\n", path, sqlite3_errmsg(sql));
    rc = EXIT_DB;
done:
    sqlite3_finalize(st);
    db_rollback(d);
    db_close(d);
    for (size_t i = 0; i < nobjs; i++)
        free(objs[i].boxes);
    free(objs);
    object_points_free(&pt);
    free(found);
    return rc;
}
