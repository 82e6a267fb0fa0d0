/* cvre-admin: read-only questions to a cvre database, safe while the server
 * runs, and a few changes: rolling a collision map back, adding, deleting
 * and setting the password of accounts, kicking sessions and banning names,
 * which reopen the database read-write for that command only. Flags, help
 * texts and exit codes live here; the SQL is in query.c, the accounts in
 * user.c, kicks and bans in moderate.c, the output forms in out.c. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "account.h"
#include "db.h"
#include "maintain.h"
#include "map.h"
#include "moderate.h"
#include "num.h"
#include "out.h"
#include "query.h"
#include "timefmt.h"
#include "user.h"

enum { EXIT_NOT_FOUND = 1, EXIT_USAGE = 2, EXIT_DB = 3, EXIT_REFUSED = 4 };

/* --limit can ask for at most this many rows: a table holds them all in
 * memory to size its columns (0 means no limit and is meant for --csv and
 * --json, which stream). */
#define ADMIN_LIMIT_MAX 100000000
#define ADMIN_LIMIT_DEFAULT 100

static const char usage[] =
    "usage: cvre-admin [--db FILE] [--csv | --json] COMMAND [options]\n"
    "\n"
    "Answers questions about a cvre database: the collision log, objects and\n"
    "their collision maps (ECM), users and sessions, accounts. It opens the file\n"
    "read-only and can run while the server writes to it; only rollback, user\n"
    "add, del and passwd, kick, ban and unban write, and retention, which\n"
    "removes old collisions.\n"
    "\n"
    "Commands:\n"
    "  collisions [filters]      collisions, newest first (--object, --user, --since,\n"
    "                            --until, --region, --limit)\n"
    "  top-objects               objects by number of collisions (--since, --until, --limit)\n"
    "  object ID                 one object: owner, placement, geometry, ECM, collisions\n"
    "  versions ID               the ECM versions of an object, their history, rejected maps\n"
    "  diff ID A B               the boxes that differ between versions A and B of an object\n"
    "  rollback ID K             make version K's boxes the object's collision map again\n"
    "                            (as a new version)\n"
    "  sessions                  who was connected when (--user, --since, --until, --limit)\n"
    "  clusters                  the latest clustering run's clusters (--object, --limit)\n"
    "  map --svg FILE            a picture of an object's collision map (--object ID,\n"
    "                            --version N) or of the whole world, and its figures\n"
    "  totals                    users, sessions, objects, collisions and the time span\n"
    "  user add NAME [--admin]   add an account; asks for its password (--password-stdin)\n"
    "  user del NAME             delete an account (its objects pass to the world account)\n"
    "  user list                 the accounts (never their password hashes)\n"
    "  user passwd NAME          set an account's password; asks for it (--password-stdin)\n"
    "  kick SESSION              have the server close a session (see sessions)\n"
    "  ban NAME [--minutes N]    bar a name from joining (N minutes, or until unbanned)\n"
    "                            and close its sessions\n"
    "  unban NAME                lift a name's ban\n"
    "  bans                      the bans in force\n"
    "  backup FILE               copy the database to a new FILE, one consistent\n"
    "                            snapshot, checked (--vacuum: compacted)\n"
    "  retention --older-than DAYS\n"
    "                            remove the collisions logged more than DAYS days ago\n"
    "  help [COMMAND]            this text, or a command's (same as COMMAND --help)\n"
    "\n"
    "Options (before or after the command):\n"
    "  --db FILE                 the database (default cvre.db)\n"
    "  --csv                     CSV (RFC 4180) with a header line and every column\n"
    "  --json                    one JSON array of objects, one object per line, every column\n"
    "  --help                    show help\n"
    "  --version                 show the version\n"
    "\n"
    "The default output is an aligned table for people; it leaves out a few\n"
    "detail columns (see each command's help), which --csv and --json include.\n"
    "Times print as ISO-8601 in UTC. NULL is \"-\" in a table, an empty CSV\n"
    "field, null in JSON.\n"
    "\n"
    "Times given to --since and --until (cvre-cluster takes the same): Unix seconds\n"
    "(1795000000 or 1795000000.25), or ISO-8601 as printed here: 2026-11-22,\n"
    "2026-11-22T10:00, 2026-11-22T10:00:00.5, 2026-11-22T10:00:00.500000Z, a space\n"
    "instead of T, and an optional zone: Z, +01:00, -0500, +01 (none means UTC).\n"
    "--since is inclusive, --until exclusive.\n"
    "\n"
    "Exit status:\n"
    "  0  success (also when no rows match)\n"
    "  1  the object, version, user, account or open session asked about does not\n"
    "     exist, or the name to unban is not banned\n"
    "  2  bad arguments (also: an empty or mistyped password)\n"
    "  3  the database cannot be used: missing or unreadable file, not a cvre\n"
    "     database, a schema version this build does not know, or a failed query\n"
    "     or write (also: map's picture could not be written)\n"
    "  4  rollback refused, nothing written: the object was removed, the version\n"
    "     is already in force, or another writer changed the object meanwhile;\n"
    "     or a user command refused, nothing written: the name is taken, or the\n"
    "     account is the reserved world account; or backup's FILE exists\n";

struct command {
    const char *name;
    unsigned opts; /* OPT_* accepted besides the common ones */
    int npos;      /* positional arguments: an object id, then versions */
    const char *help;
};

/* Most positional arguments of a command (diff: ID A B). */
#define ADMIN_POS_MAX 3

enum { OPT_OBJECT = 1, OPT_USER = 2, OPT_SINCE = 4, OPT_UNTIL = 8, OPT_REGION = 16, OPT_LIMIT = 32, OPT_SVG = 64,
       OPT_MAPVERSION = 128, OPT_ADMIN = 256, OPT_PASSWORD_STDIN = 512, OPT_MINUTES = 1024, OPT_VACUUM = 2048,
       OPT_OLDER_THAN = 4096 };

static const struct command commands[] = {
    {"collisions", OPT_OBJECT | OPT_USER | OPT_SINCE | OPT_UNTIL | OPT_REGION | OPT_LIMIT, 0,
     "usage: cvre-admin collisions [--object ID] [--user NAME] [--since T] [--until T]\n"
     "                             [--region X0,Y0,Z0,X1,Y1,Z1] [--limit N]\n"
     "\n"
     "Collisions matching every filter given, newest first.\n"
     "\n"
     "  --object ID       on this object (exit 1 if there is no such object)\n"
     "  --user NAME       by this user (exit 1 if there is no such user)\n"
     "  --since T         at or after T\n"
     "  --until T         before T\n"
     "  --region BOX      world contact point inside the box with corners X0,Y0,Z0 and\n"
     "                    X1,Y1,Z1 (metres, X0 <= X1 and so on; edges included),\n"
     "                    looked up through the spatial index\n"
     "  --limit N         at most N rows (default 100; 0: all)\n"
     "\n"
     "Columns: id, time, user, session*, avatar*, object, version (ECM), box, inside\n"
     "(the avatar was already inside the box), world_x/y/z (contact point),\n"
     "local_x/y/z* (contact point in object coordinates), normal_x/y/z*,\n"
     "velocity_x/y/z* (m/s). * only with --csv and --json.\n"},
    {"top-objects", OPT_SINCE | OPT_UNTIL | OPT_LIMIT, 0,
     "usage: cvre-admin top-objects [--since T] [--until T] [--limit N]\n"
     "\n"
     "Objects by number of collisions in the time range, most first.\n"
     "\n"
     "  --since T, --until T   count collisions at or after T, before T\n"
     "  --limit N              at most N objects (default 100; 0: all)\n"
     "\n"
     "Columns: object, name, owner, collisions, users (distinct, known ones),\n"
     "first, last (collision times), in_world* (not removed).\n"
     "* only with --csv and --json.\n"},
    {"object", 0, 1,
     "usage: cvre-admin object ID\n"
     "\n"
     "One object: name, format, owner, when it was created (and removed), its\n"
     "placement (pos_x/y/z in metres, yaw in radians about +y, scale), triangle\n"
     "count and bounding box (mbr_*, object coordinates), its ECM version in\n"
     "force, how many versions it has had and how many boxes the current one\n"
     "has, and its collisions: in all, in the current version, distinct users,\n"
     "first and last. Exit 1 if there is no such object.\n"},
    {"versions", 0, 1,
     "usage: cvre-admin versions ID\n"
     "\n"
     "The ECM versions of an object, oldest first, and why each was made, with\n"
     "the refined maps the judge turned down (never published) after the\n"
     "version they were judged against.\n"
     "\n"
     "Columns: version, created, reason (import, refine, rollback; rejected for\n"
     "a candidate, whose version is \"-\"), parent (the version in force it\n"
     "replaced, or was judged against), run (the cvre-cluster or online run\n"
     "that caused it), clusters (that run's clusters it answers, e.g. 3,4),\n"
     "restores (for a rollback: the version whose boxes it copies), boxes,\n"
     "collisions logged against it, current (yes: the version in force),\n"
     "detail (free text; a refinement's says what the judge found: samples,\n"
     "moves, phantom blocks and moves into geometry, old -> new; a rejected\n"
     "candidate's starts \"candidate N:\"). Empty history fields (\"-\") for\n"
     "imports. Exit 1 if there is no such object.\n"},
    {"diff", 0, 3,
     "usage: cvre-admin diff ID A B\n"
     "\n"
     "What changed from version A to version B of object ID's collision map: a\n"
     "summary, then every box only in A, only in B, or in both. A box is in both\n"
     "when its six coordinates are exactly equal (a box listed twice in A must be\n"
     "listed twice in B).\n"
     "\n"
     "Summary: object, a, b, boxes_a, boxes_b, only_a, only_b, both, volume_a,\n"
     "volume_b (sums of box volumes in m^3 of object coordinates; overlaps count\n"
     "twice). Boxes: change (only_a, only_b, both), box_a, box_b (its index in\n"
     "each version), min_x/y/z, max_x/y/z (object coordinates), volume; the\n"
     "changes first. A table rounds to 3 decimals: --json and --csv give the\n"
     "exact values. --json prints one object, {\"summary\": {...}, \"boxes\": [...]};\n"
     "--csv prints the boxes only (the summary adds them up).\n"
     "\n"
     "Exit 1 if there is no such object or version.\n"},
    {"rollback", 0, 2,
     "usage: cvre-admin rollback ID K\n"
     "\n"
     "Puts version K's boxes back in force for object ID. Versions only grow:\n"
     "this writes a new version N+1 (reason rollback, restores K, parent the\n"
     "version in force) through the same path as a refinement, so a running\n"
     "server publishes it to its clients like any other change. Prints the new\n"
     "version: object, version, parent, restores, reason, boxes, created, detail.\n"
     "\n"
     "It writes: after the usual read-only open has checked the schema version,\n"
     "it opens the database read-write (it never migrates one). Safe while the\n"
     "server runs.\n"
     "\n"
     "Exit 1 if there is no such object or version K; 4, with nothing written,\n"
     "if the object was removed, if K is in force or the version in force has\n"
     "K's boxes already (nothing to do), or if another writer changed the object\n"
     "meanwhile (look again and retry); 3 if the write failed.\n"},
    {"sessions", OPT_USER | OPT_SINCE | OPT_UNTIL | OPT_LIMIT, 0,
     "usage: cvre-admin sessions [--user NAME] [--since T] [--until T] [--limit N]\n"
     "\n"
     "Sessions connected at some moment between --since and --until, newest\n"
     "first (a session still open counts as connected until now).\n"
     "\n"
     "  --user NAME            this user's only (exit 1 if there is no such user)\n"
     "  --since T, --until T   the time range\n"
     "  --limit N              at most N sessions (default 100; 0: all)\n"
     "\n"
     "Columns: session, user, peer (address:port), avatar*, started, joined*,\n"
     "ended, reason, duration (h:mm:ss in a table, seconds otherwise).\n"
     "* only with --csv and --json.\n"},
    {"clusters", OPT_OBJECT | OPT_LIMIT, 0,
     "usage: cvre-admin clusters [--object ID] [--limit N]\n"
     "\n"
     "The clusters the latest cvre-cluster run found, largest first: run,\n"
     "finished, object, version (ECM), cluster, points, users, box (the ECM box\n"
     "nearest its centroid; refinement takes every box its points lie on) and\n"
     "the centroid in object-local coordinates. Nothing if the job never ran.\n"},
    {"map", OPT_OBJECT | OPT_SVG | OPT_MAPVERSION, 0,
     "usage: cvre-admin map --svg FILE [--object ID [--version N]] [--json]\n"
     "       cvre-admin map --json [--object ID [--version N]]\n"
     "\n"
     "Draws collision maps as an SVG picture and prints their figures. With\n"
     "--object, one object at version N (default: the version in force); without,\n"
     "the whole world: every object in it at its version in force.\n"
     "\n"
     "  --svg FILE        write the picture to FILE (replaced)\n"
     "  --object ID       this object only (exit 1 if there is none, or it was removed)\n"
     "  --version N       this version of it (exit 1 if there is none)\n"
     "  --json            the figures as JSON: one object for --object, else an array\n"
     "\n"
     "The picture has two views side by side in world metres, TOP (looking down:\n"
     "x right, z down the page) and SIDE (x right, y up): the geometry's outline\n"
     "(grey), the original boxes (version 1, dashed), the boxes of the version shown\n"
     "(filled; a box turned by a yaw that is not a multiple of 90 degrees as its\n"
     "world AABB, as the server sees it), and the collision points: those against\n"
     "the version's parent (what a refinement answered), or against the version\n"
     "itself if it has none, coloured by cluster (noise grey). Clusters are\n"
     "recomputed with DBSCAN over exactly those points, with the parameters of the\n"
     "run that made the version, else of the latest run with clusters over those\n"
     "points; without one every point is grey. At most 20,000 points are drawn (an\n"
     "evenly spaced subsample in id order beyond that, which the caption says).\n"
     "The same database gives the same file, byte for byte.\n"
     "\n"
     "Figures (a table, or --json): object, name, version, boxes, original_boxes\n"
     "(version 1), box_volume (sum of the boxes' volumes, m^3 of the world: local\n"
     "volume times scale^3), union_volume (the volume their union covers, overlaps\n"
     "once), occupied_volume (the geometry: the cells a 2^7-per-axis digitization\n"
     "of the object's MBR marks), tightness (occupied_volume / union_volume; 1 for\n"
     "a map of one box per occupied cell), full_voxel_boxes (those cells: the box\n"
     "count of that map), depth (7), points, clusters, and points_drawn,\n"
     "points_version (the version the points were logged against), run (whose\n"
     "parameters, or null).\n"},
    {"totals", 0, 0,
     "usage: cvre-admin totals\n"
     "\n"
     "Counts of users, sessions (and open ones), objects (and those still in the\n"
     "world) and collisions, and the first and last moment the database knows\n"
     "of (session starts and ends, collisions).\n"},
    {"user", OPT_ADMIN | OPT_PASSWORD_STDIN, 0,
     "usage: cvre-admin user add NAME [--admin] [--password-stdin]\n"
     "       cvre-admin user del NAME\n"
     "       cvre-admin user list\n"
     "       cvre-admin user passwd NAME [--password-stdin]\n"
     "\n"
     "Accounts: who may log in to the server, with a password (Argon2id; only\n"
     "its hash is stored). A name is 1 to 32 bytes of UTF-8 without spaces,\n"
     "control or invisible characters, unique ignoring ASCII case; \"world\"\n"
     "is reserved: the account the world file's objects belong to, which\n"
     "cannot log in and cannot be deleted.\n"
     "\n"
     "  add NAME          add an account and print it\n"
     "  --admin           (add) the account is a world admin\n"
     "  del NAME          delete an account and print how many of its objects in\n"
     "                    the world now belong to the world account; its resume\n"
     "                    tokens go with it, its sessions and collisions stay\n"
     "  list              every account\n"
     "  passwd NAME       set an account's password and print it; its resume\n"
     "                    tokens are revoked (every device logs in again)\n"
     "  --password-stdin  (add, passwd) read the password as one line of standard\n"
     "                    input instead of asking twice on the terminal\n"
     "\n"
     "add and passwd ask for the password on the terminal, without echo, twice;\n"
     "an empty password is refused. Standard input that is not a terminal needs\n"
     "--password-stdin. A password is never printed, logged or stored.\n"
     "\n"
     "Columns: id, name, admin, can_log_in (has a password), created,\n"
     "password_set (when its password was last set), tokens (resume tokens not\n"
     "expired), objects (in the world, owned under its name).\n"
     "\n"
     "The three that write open the database read-write after the read-only\n"
     "open has checked its schema version (they never migrate one); safe while\n"
     "the server runs. Exit 1 if there is no such account (del, passwd); 2 for\n"
     "a bad name or an empty, too long or mistyped password; 4, with nothing\n"
     "written, if the name is taken (add) or the account is world (del, passwd);\n"
     "3 if the database cannot be used or the write failed.\n"},
    {"kick", 0, 0,
     "usage: cvre-admin kick SESSION\n"
     "\n"
     "Asks every running server to close session SESSION (its number in\n"
     "cvre-admin sessions and in the client's welcome): the client gets bye\n"
     "(reason kicked) and is disconnected within about a second, and the\n"
     "session ends with reason kicked. Nobody else notices. Nothing stops it\n"
     "from joining again: ban its name for that. Prints the session: session,\n"
     "user, peer, started, joined.\n"
     "\n"
     "It writes (an action in the admin_events feed that servers follow), after\n"
     "the read-only open has checked the schema version; safe while the server\n"
     "runs. Exit 1, nothing written, if no session SESSION is open; 3 if the\n"
     "write failed.\n"},
    {"ban", OPT_MINUTES, 0,
     "usage: cvre-admin ban NAME [--minutes N]\n"
     "\n"
     "Bars NAME from joining, as an account or as a guest, in any letter case,\n"
     "and asks every running server to close the sessions joined under it: they\n"
     "get bye (reason kicked) within about a second, their sessions end with\n"
     "reason banned, and their next join is refused (\"NAME is banned\"). An\n"
     "account's resume tokens are revoked. A name may be banned before anyone\n"
     "uses it. Banning a banned name sets its new end. Prints the ban: name,\n"
     "until, since.\n"
     "\n"
     "  --minutes N       for N minutes (a whole number from 1 to 52596000, 100\n"
     "                    years); without it, until unbanned\n"
     "\n"
     "A name is 1 to 32 bytes without control characters. It writes, like kick;\n"
     "safe while the server runs. Exit 2 for a bad name or --minutes; 3 if the\n"
     "write failed.\n"},
    {"unban", 0, 0,
     "usage: cvre-admin unban NAME\n"
     "\n"
     "Lifts NAME's ban (any letter case): it may join again at once. Prints the\n"
     "ban it lifted: name, until, since. It writes, like kick; safe while the\n"
     "server runs. Exit 1, nothing written, if NAME is not banned (a ban whose\n"
     "time is up is not); 3 if the write failed.\n"},
    {"bans", 0, 0,
     "usage: cvre-admin bans\n"
     "\n"
     "The bans in force, oldest first: name, until (when it ends, or never:\n"
     "until unbanned), since (when the name was banned).\n"},
    {"backup", OPT_VACUUM, 0, maintain_backup_help},
    {"retention", OPT_OLDER_THAN, 0, maintain_retention_help},
};

static const char *prog = "cvre-admin";

/* Prints "cvre-admin [COMMAND]: message (see ... --help)"; returns the
 * usage exit status. */
static int usage_error(const char *cmd, const char *fmt, ...) __attribute__((format(printf, 2, 3)));
static int usage_error(const char *cmd, const char *fmt, ...)
{
    va_list ap;
    fprintf(stderr, "%s%s%s: ", prog, cmd ? " " : "", cmd ? cmd : "");
    va_start(ap, fmt);
    vfprintf(stderr, fmt, ap);
    va_end(ap);
    fprintf(stderr, " (see %s%s%s --help)\n", prog, cmd ? " " : "", cmd ? cmd : "");
    return EXIT_USAGE;
}

/* X0,Y0,Z0,X1,Y1,Z1 with X0 <= X1, Y0 <= Y1, Z0 <= Z1. */
static int parse_region(const char *text, double box[6])
{
    const char *p = text;
    for (int i = 0; i < 6; i++) {
        char buf[64];
        size_t n = strcspn(p, ",");
        if (n == 0 || n >= sizeof buf || (i < 5 && p[n] != ',') || (i == 5 && p[n]))
            return -EINVAL;
        memcpy(buf, p, n);
        buf[n] = 0;
        if (num_parse_real(buf, -INFINITY, INFINITY, &box[i]) < 0)
            return -EINVAL;
        p += n + (i < 5);
    }
    return box[0] <= box[3] && box[1] <= box[4] && box[2] <= box[5] ? 0 : -EINVAL;
}

static const struct command *find_command(const char *name)
{
    for (size_t i = 0; i < sizeof commands / sizeof commands[0]; i++)
        if (strcmp(commands[i].name, name) == 0)
            return &commands[i];
    return NULL;
}

enum { O_DB = 256, O_CSV, O_JSON, O_HELP, O_VERSION, O_OBJECT, O_USER, O_SINCE, O_UNTIL, O_REGION, O_LIMIT, O_SVG,
       O_MAPVERSION, O_ADMIN, O_PASSWORD_STDIN, O_MINUTES, O_VACUUM, O_OLDER_THAN };

/* Every command's options but --version, whose meaning depends on it. */
#define SHARED_OPTIONS                                                                                              \
    {"db", required_argument, 0, O_DB}, {"csv", no_argument, 0, O_CSV}, {"json", no_argument, 0, O_JSON},           \
        {"help", no_argument, 0, O_HELP}, {"object", required_argument, 0, O_OBJECT},                               \
        {"user", required_argument, 0, O_USER}, {"since", required_argument, 0, O_SINCE},                           \
        {"until", required_argument, 0, O_UNTIL}, {"region", required_argument, 0, O_REGION},                       \
        {"limit", required_argument, 0, O_LIMIT}, {"svg", required_argument, 0, O_SVG},                           \
        {"admin", no_argument, 0, O_ADMIN}, {"password-stdin", no_argument, 0, O_PASSWORD_STDIN},             \
        {"minutes", required_argument, 0, O_MINUTES}, {"vacuum", no_argument, 0, O_VACUUM},                       \
        {"older-than", required_argument, 0, O_OLDER_THAN}

static const struct option options[] = {
    SHARED_OPTIONS,
    {"version", no_argument, 0, O_VERSION},
    {0, 0, 0, 0},
};

/* map's options: the same, except that --version names an ECM version. */
static const struct option map_options[] = {
    SHARED_OPTIONS,
    {"version", required_argument, 0, O_MAPVERSION},
    {0, 0, 0, 0},
};

struct args {
    const char *db;
    int format, help, version;
    query_filter f;
    const char *svg;      /* map --svg */
    uint32_t map_version; /* map --version; 0: none given */
    user_request user;    /* user: --admin, --password-stdin (the verb and name come later) */
    moderate_request mod; /* kick, ban, unban, bans: --minutes (the rest comes later) */
    maintain_request maint; /* backup --vacuum, retention --older-than (the file comes later) */
};

/* Parses options from argv[1..] (argv[0] names the program or the command).
 * cmd is NULL before the command: only the common options are taken, and
 * parsing stops at the first word that is not an option. Returns 0 or an
 * exit status. */
static int parse_options(int argc, char **argv, const struct command *cmd, struct args *a)
{
    static const unsigned bit[] = {[O_OBJECT - O_OBJECT] = OPT_OBJECT, [O_USER - O_OBJECT] = OPT_USER,
                                   [O_SINCE - O_OBJECT] = OPT_SINCE,   [O_UNTIL - O_OBJECT] = OPT_UNTIL,
                                   [O_REGION - O_OBJECT] = OPT_REGION, [O_LIMIT - O_OBJECT] = OPT_LIMIT,
                                   [O_SVG - O_OBJECT] = OPT_SVG,       [O_MAPVERSION - O_OBJECT] = OPT_MAPVERSION,
                                   [O_ADMIN - O_OBJECT] = OPT_ADMIN,   [O_PASSWORD_STDIN - O_OBJECT] = OPT_PASSWORD_STDIN,
                                   [O_MINUTES - O_OBJECT] = OPT_MINUTES, [O_VACUUM - O_OBJECT] = OPT_VACUUM,
                                   [O_OLDER_THAN - O_OBJECT] = OPT_OLDER_THAN};
    const struct option *table = cmd && (cmd->opts & OPT_MAPVERSION) ? map_options : options;
    const char *where = cmd ? cmd->name : NULL;
    int o, li = 0;
    long long n;
    optind = 0; /* glibc: start afresh, argv[0] is skipped */
    opterr = 0;
    while ((o = getopt_long(argc, argv, cmd ? ":" : "+:", table, &li)) != -1) {
        if (o == '?')
            return usage_error(where, "unknown option %s", argv[optind - 1]);
        if (o == ':')
            return usage_error(where, "%s needs a value", argv[optind - 1]);
        if (o >= O_OBJECT && (!cmd || !(cmd->opts & bit[o - O_OBJECT])))
            return usage_error(where, cmd ? "--%s is not an option of this command" : "--%s must come after the command",
                               table[li].name);
        switch (o) {
        case O_DB: a->db = optarg; break;
        case O_CSV: a->format = OUT_CSV; break;
        case O_JSON: a->format = OUT_JSON; break;
        case O_HELP: a->help = 1; break;
        case O_VERSION: a->version = 1; break;
        case O_OBJECT:
            if (num_parse_int(optarg, 1, INT64_MAX, &n) < 0)
                return usage_error(where, "--object wants a positive whole number, not \"%s\"", optarg);
            a->f.has_object = 1;
            a->f.object = n;
            break;
        case O_USER: a->f.user = optarg; break;
        case O_SINCE:
        case O_UNTIL: {
            double t;
            if (timefmt_parse(optarg, &t) < 0)
                return usage_error(where, "not a time: \"%s\"", optarg);
            if (o == O_SINCE)
                a->f.has_since = 1, a->f.since = t;
            else
                a->f.has_until = 1, a->f.until = t;
            break;
        }
        case O_REGION:
            if (parse_region(optarg, a->f.region) < 0)
                return usage_error(where, "--region wants X0,Y0,Z0,X1,Y1,Z1 with X0 <= X1, Y0 <= Y1, Z0 <= Z1, not \"%s\"",
                                   optarg);
            a->f.has_region = 1;
            break;
        case O_LIMIT:
            if (num_parse_int(optarg, 0, ADMIN_LIMIT_MAX, &n) < 0)
                return usage_error(where, "--limit wants a whole number from 0 to 100000000, not \"%s\"", optarg);
            a->f.limit = n;
            break;
        case O_SVG:
            if (!*optarg)
                return usage_error(where, "--svg wants a file name");
            a->svg = optarg;
            break;
        case O_MAPVERSION:
            if (num_parse_int(optarg, 1, UINT32_MAX, &n) < 0)
                return usage_error(where, "--version wants a version number from 1 to %u, not \"%s\"", UINT32_MAX,
                                   optarg);
            a->map_version = (uint32_t)n;
            break;
        case O_ADMIN: a->user.admin = 1; break;
        case O_PASSWORD_STDIN: a->user.password_stdin = 1; break;
        case O_MINUTES:
            if (num_parse_int(optarg, 1, MODERATE_MINUTES_MAX, &n) < 0)
                return usage_error(where, "--minutes wants a whole number from 1 to %lld, not \"%s\"",
                                   MODERATE_MINUTES_MAX, optarg);
            a->mod.minutes = n;
            break;
        case O_VACUUM: a->maint.vacuum = 1; break;
        case O_OLDER_THAN:
            if (num_parse_int(optarg, 1, MAINTAIN_DAYS_MAX, &n) < 0)
                return usage_error(where, "--older-than wants a whole number of days from 1 to %lld, not \"%s\"",
                                   MAINTAIN_DAYS_MAX, optarg);
            a->maint.days = n;
            break;
        }
    }
    return 0;
}

/* The one place a command's result (query.h: 0 or a negative errno) becomes
 * the exit status the usage text documents; prints the message of a
 * failure. */
static int exit_status(int rc, const char *err)
{
    if (rc == 0)
        return 0;
    fprintf(stderr, "%s: %s\n", prog, err);
    switch (rc) {
    case -ENOENT: return EXIT_NOT_FOUND;
    case -EPERM: return EXIT_REFUSED;
    case -EINVAL: return EXIT_USAGE;
    default: return EXIT_DB;
    }
}

/* The one write. The read-only handle ro (whose open checked the schema
 * version) checks the request and is closed; only then is the file opened
 * read-write, so that a database of another version is never migrated and
 * a refused request never opens it for writing. */
static int rollback(db *ro, const char *path, int format, int64_t id, uint32_t k)
{
    char err[512] = "";
    uint32_t in_force = 0;
    int rc = query_rollback_check(db_sqlite(ro), id, k, &in_force, err, sizeof err);
    db_close(ro);
    if (rc != 0)
        return exit_status(rc, err);
    db *d = db_open(path, DB_READWRITE, err, sizeof err);
    if (!d) {
        fprintf(stderr, "%s: cannot open for writing: %s\n", prog, err);
        return EXIT_DB;
    }
    rc = query_rollback(d, id, k, in_force, format, err, sizeof err);
    db_close(d);
    return exit_status(rc, err);
}

/* Checks the words after `user` (argv[0..argc)) into a->user: a verb, a
 * name for all but list, the options that verb takes, a valid name for add,
 * and a way to read the password. Returns 0 or the usage exit status. */
static int user_arguments(int argc, char **argv, struct args *a)
{
    user_request *r = &a->user;
    if (argc < 1)
        return usage_error("user", "%s", "wants add, del, list or passwd");
    r->verb = user_verb(argv[0]);
    if (r->verb < 0)
        return usage_error("user", "no user command \"%s\"", argv[0]);
    int want = r->verb == USER_LIST ? 0 : 1;
    if (argc - 1 < want)
        return usage_error("user", "%s wants the account's name", argv[0]);
    if (argc - 1 > want)
        return usage_error("user", "unexpected argument \"%s\"", argv[1 + want]);
    r->name = want ? argv[1] : NULL;
    if (r->admin && r->verb != USER_ADD)
        return usage_error("user", "%s", "--admin is an option of user add only");
    if (r->password_stdin && r->verb != USER_ADD && r->verb != USER_PASSWD)
        return usage_error("user", "%s", "--password-stdin is an option of user add and user passwd only");
    char why[128];
    if (r->verb == USER_ADD && db_account_name_check(r->name, why, sizeof why) < 0)
        return usage_error("user", "not a name for an account: %s", why);
    if ((r->verb == USER_ADD || r->verb == USER_PASSWD) && !r->password_stdin && !isatty(STDIN_FILENO))
        return usage_error("user", "%s",
                           "asks for the password on a terminal: give --password-stdin to read it from standard input");
    return 0;
}

/* Checks the words after kick, ban or unban (argv[0..argc)) into a->mod:
 * one session number or one name that may be banned; bans takes none.
 * Returns 0 or the usage exit status. */
static int moderate_arguments(const char *cmd, int argc, char **argv, struct args *a)
{
    moderate_request *r = &a->mod;
    int want = r->verb == MODERATE_BANS ? 0 : 1;
    long long n = 0;
    if (argc > want)
        return usage_error(cmd, "unexpected argument \"%s\"", argv[want]);
    if (argc < want)
        return usage_error(cmd, "%s", r->verb == MODERATE_KICK ? "wants a session number" : "wants a name");
    if (r->verb == MODERATE_KICK && num_parse_int(argv[0], 1, INT64_MAX, &n) < 0)
        return usage_error(cmd, "wants a positive whole number as the session, not \"%s\"", argv[0]);
    if (r->verb == MODERATE_KICK)
        r->session = n;
    char why[128];
    if ((r->verb == MODERATE_BAN || r->verb == MODERATE_UNBAN) && moderate_name_check(argv[0], why, sizeof why) < 0)
        return usage_error(cmd, "not a name: %s", why);
    r->name = want ? argv[0] : NULL;
    return 0;
}

/* Checks the words after backup or retention (argv[0..argc)) into a->maint:
 * backup's file; retention takes none, but --older-than. Returns 0 or the
 * usage exit status. */
static int maintain_arguments(const char *cmd, int argc, char **argv, struct args *a)
{
    int want = a->maint.verb == MAINTAIN_BACKUP ? 1 : 0;
    if (argc > want)
        return usage_error(cmd, "unexpected argument \"%s\"", argv[want]);
    if (argc < want || (want && !*argv[0]))
        return usage_error(cmd, "%s", "wants the file to copy the database to");
    if (!want && !a->maint.days)
        return usage_error(cmd, "%s", "wants --older-than DAYS");
    a->maint.file = want ? argv[0] : NULL;
    return 0;
}

static int run_command(const struct command *cmd, db *d, struct args *a, const int64_t *pos)
{
    sqlite3 *s = db_sqlite(d);
    char err[512] = "";
    int rc;
    int64_t id = pos[0];
    if (strcmp(cmd->name, "collisions") == 0)
        rc = query_collisions(s, &a->f, a->format, err, sizeof err);
    else if (strcmp(cmd->name, "top-objects") == 0)
        rc = query_top_objects(s, &a->f, a->format, err, sizeof err);
    else if (strcmp(cmd->name, "object") == 0)
        rc = query_object(s, id, a->format, err, sizeof err);
    else if (strcmp(cmd->name, "versions") == 0)
        rc = query_versions(s, id, a->format, err, sizeof err);
    else if (strcmp(cmd->name, "diff") == 0)
        rc = query_diff(s, id, (uint32_t)pos[1], (uint32_t)pos[2], a->format, err, sizeof err);
    else if (strcmp(cmd->name, "sessions") == 0)
        rc = query_sessions(s, &a->f, a->format, err, sizeof err);
    else if (strcmp(cmd->name, "clusters") == 0)
        rc = query_clusters(s, &a->f, a->format, err, sizeof err);
    else if (strcmp(cmd->name, "map") == 0) {
        map_request r = {.has_object = a->f.has_object, .object = a->f.object, .version = a->map_version,
                         .svg = a->svg, .json = a->format == OUT_JSON};
        rc = map_run(d, &r, err, sizeof err);
    }
    else
        rc = query_totals(s, a->format, err, sizeof err);
    return exit_status(rc, err);
}

int main(int argc, char **argv)
{
    struct args a = {.db = "cvre.db", .format = OUT_TABLE, .f = {.limit = ADMIN_LIMIT_DEFAULT}};
    int rc = parse_options(argc, argv, NULL, &a);
    if (rc)
        return rc;
    if (a.version) {
        printf("cvre-admin %s (schema version %d)\n", CVRE_VERSION, db_schema_version());
        return 0;
    }
    if (a.help) {
        fputs(usage, stdout);
        return 0;
    }
    if (optind >= argc)
        return usage_error(NULL, "%s", "no command given");
    const char *name = argv[optind];
    int sub_argc = argc - optind;
    char **sub_argv = argv + optind;
    if (strcmp(name, "help") == 0) {
        const struct command *c = sub_argc > 1 ? find_command(sub_argv[1]) : NULL;
        if (sub_argc > 1 && !c)
            return usage_error(NULL, "no command \"%s\"", sub_argv[1]);
        fputs(c ? c->help : usage, stdout);
        return 0;
    }
    const struct command *cmd = find_command(name);
    if (!cmd)
        return usage_error(NULL, "no command \"%s\"", name);
    rc = parse_options(sub_argc, sub_argv, cmd, &a);
    if (rc)
        return rc;
    if (a.help) {
        fputs(cmd->help, stdout);
        return 0;
    }
    int64_t pos[ADMIN_POS_MAX] = {0};
    int positional = sub_argc - optind;
    if (strcmp(cmd->name, "user") == 0 && (rc = user_arguments(positional, sub_argv + optind, &a)) != 0)
        return rc;
    a.mod.verb = moderate_verb(cmd->name);
    if (a.mod.verb >= 0 && (rc = moderate_arguments(cmd->name, positional, sub_argv + optind, &a)) != 0)
        return rc;
    a.maint.verb = maintain_verb(cmd->name);
    if (a.maint.verb >= 0 && (rc = maintain_arguments(cmd->name, positional, sub_argv + optind, &a)) != 0)
        return rc;
    if (strcmp(cmd->name, "user") == 0 || a.mod.verb >= 0 || a.maint.verb >= 0)
        positional = 0; /* taken: a verb, a name, a session or a file, not object ids */
    if (positional > cmd->npos)
        return usage_error(cmd->name, "unexpected argument \"%s\"", sub_argv[optind + cmd->npos]);
    if (positional < cmd->npos)
        return usage_error(cmd->name, "%s",
                           cmd->npos == 1 ? "wants an object id"
                                          : cmd->npos == 2 ? "wants an object id and a version" : "wants an object id and two versions");
    for (int i = 0; i < cmd->npos; i++) {
        long long n;
        const char *text = sub_argv[optind + i];
        if (i == 0 && num_parse_int(text, 1, INT64_MAX, &n) < 0)
            return usage_error(cmd->name, "wants a positive whole number as the object id, not \"%s\"", text);
        if (i > 0 && num_parse_int(text, 1, UINT32_MAX, &n) < 0)
            return usage_error(cmd->name, "wants a version number from 1 to %u, not \"%s\"", UINT32_MAX, text);
        pos[i] = n;
    }
    if (a.format == OUT_TABLE && a.f.limit == 0)
        a.f.limit = ADMIN_LIMIT_MAX; /* a table is held in memory */
    if (strcmp(cmd->name, "map") == 0) {
        if (a.format == OUT_CSV)
            return usage_error(cmd->name, "%s", "prints its figures as a table or --json, not --csv");
        if (!a.svg && a.format != OUT_JSON)
            return usage_error(cmd->name, "%s", "wants --svg FILE, --json or both");
        if (a.map_version && !a.f.has_object)
            return usage_error(cmd->name, "%s", "--version needs --object: the world map shows the versions in force");
    }

    if (access(a.db, F_OK) != 0) {
        fprintf(stderr, "%s: %s: %s (give the database with --db FILE)\n", prog, a.db, strerror(errno));
        return EXIT_DB;
    }
    char err[512];
    db *d = db_open(a.db, DB_READONLY, err, sizeof err);
    if (!d) {
        fprintf(stderr, "%s: not usable as a cvre database: %s\n", prog, err);
        return EXIT_DB;
    }
    sqlite3 *s = db_sqlite(d);
    /* Belt and braces on top of the read-only open. */
    if (sqlite3_exec(s, "PRAGMA query_only = 1", NULL, NULL, NULL) != SQLITE_OK) {
        fprintf(stderr, "%s: %s: %s\n", prog, a.db, sqlite3_errmsg(s));
        db_close(d);
        return EXIT_DB;
    }
    if (strcmp(cmd->name, "rollback") == 0)
        return rollback(d, a.db, a.format, pos[0], (uint32_t)pos[1]);
    if (strcmp(cmd->name, "user") == 0) {
        rc = user_run(d, a.db, &a.user, a.format, err, sizeof err);
        return exit_status(rc, err);
    }
    if (a.mod.verb >= 0) {
        rc = moderate_run(d, a.db, &a.mod, a.format, err, sizeof err);
        return exit_status(rc, err);
    }
    if (a.maint.verb >= 0) {
        rc = maintain_run(d, a.db, &a.maint, a.format, err, sizeof err);
        return exit_status(rc, err);
    }
    rc = run_command(cmd, d, &a, pos);
    db_close(d);
    return rc;
}
