/* cvre-server: flags, start-up and the one line that says it is ready. */
#include <errno.h>
#include <getopt.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/resource.h>

#include "alloc.h"
#include "log.h"
#include "num.h"
#include "refine.h"
#include "srv_limits.h"
#include "server.h"

_Static_assert(ECM_MAX_BOXES_LIMIT <= PROTO_OBJECT_BOXES_MAX, "--refine-max-boxes fits one OBJECT_INFO");

static const char usage[] =
    "usage: cvre-server [options]\n"
    "\n"
    "Serves a shared 3D world over TCP (protocol/PROTOCOL.md) and records\n"
    "sessions in an SQLite database.\n"
    "\n"
    "  --host HOST               address to listen on (default 127.0.0.1)\n"
    "  --auth MODE               guests: anyone may walk and look, accounts may also\n"
    "                            upload, place and remove objects (default);\n"
    "                            required: accounts only (for any public address)\n"
    "  --login-burst N           logins (password or token) an address may make at\n"
    "                            once, then one every 2 s (default 5)\n"
    "  --quota-objects N         objects one account may have in the world (default 100)\n"
    "  --quota-mb N              megabytes of mesh one account may have (default 128)\n"
    "  --max-per-address N       connections open from one address; 0: no limit\n"
    "                            (default 64)\n"
    "  --joins-per-second N      joins per address per second, bursts of twice that;\n"
    "                            0: no limit (default 10)\n"
    "  --port PORT               TCP port; 0 picks a free one (default 7878)\n"
    "  --db FILE                 SQLite database, created if missing (default cvre.db)\n"
    "  --tick-hz N               simulation ticks per second, 1..240 (default 20)\n"
    "  --max-clients N           connections at once, 1..65535 (default 10000)\n"
    "  --aoi-radius M            area-of-interest radius in metres (default 64)\n"
    "  --max-speed M             avatar speed limit in m/s (default 5)\n"
    "  --world-size M            world extent in x and z, centred on 0, 10..8192\n"
    "                            (default 1000)\n"
    "  --spawn-radius M          avatars spawn within M of the centre, outside every\n"
    "                            object, at most half the world size (default 8)\n"
    "  --handshake-timeout MS    hello and join must arrive within MS (default 5000)\n"
    "  --idle-timeout MS         close clients silent for MS (default 30000)\n"
    "  --seed N                  seed for spawn points (default 1)\n"
    "  --world FILE              preload the objects a world file lists (see server/worlds/)\n"
    "  --max-upload BYTES        largest model file a client may upload, at most\n"
    "                            67108864 (default 16777216)\n"
    "  --max-triangles N         most triangles in one model, at most 4000000 (default)\n"
    "  --importer PATH           the isolated importer every model is parsed in\n"
    "                            (default: cvre-import beside cvre-server)\n"
    "  --import-memory MB        the importer's address space (default 4096)\n"
    "  --import-cpu S            the importer's CPU seconds per model (default 30)\n"
    "  --refine-interval S       seconds between looks at new collisions for clusters\n"
    "                            and refinements; 0 turns the online loop off (default 10)\n"
    "  --refine-eps M            cluster radius in metres (default 0.5)\n"
    "  --refine-min-points N     collisions within eps to make a cluster core (default 10)\n"
    "  --refine-min-users N      distinct users a cluster needs (default 3)\n"
    "  --refine-depth D          refinement grid: 2^D cells per axis of a box, 2..8 (default 7)\n"
    "  --refine-max-boxes N      most boxes per object, 1..1024 (default 64)\n"
    "  --refine-max-empty F      share of a merged box that may be empty space, 0..1 (default 0.25)\n"
    "  --refine-threads N        most threads a refinement runs on, 0..16; 0: one per\n"
    "                            CPU (default 0); 1 leaves the other cores to the tick\n"
    "  --stats-file FILE         append per-interval figures as JSON lines\n"
    "  --stats-interval S        seconds between stats lines (default 10)\n"
    "  --metrics HOST:PORT       serve Prometheus metrics at http://HOST:PORT/metrics\n"
    "                            ([IPV6]:PORT; port 0 picks a free one, logged as\n"
    "                            \"metrics on http://...\"); off by default\n"
    "  --web HOST:PORT           serve the browser client over HTTP/1.1 at\n"
    "                            http://HOST:PORT/ (its files from --web-root) and\n"
    "                            the game protocol over a WebSocket there (binary\n"
    "                            messages, one frame each); port 0 picks a free one,\n"
    "                            logged as \"web on http://...\"; off by default\n"
    "  --web-root DIR            the web client's files (default client/web under\n"
    "                            the current directory)\n"
    "  --web-origin LIST         let pages of these origins open a WebSocket too\n"
    "                            (comma-separated, as https://play.example.org;\n"
    "                            * for any); by default only the server's own\n"
    "                            pages and clients sending no Origin header can\n"
    "  --log-level LEVEL         debug, info, warn or error (default info)\n"
    "  --help                    show this help\n"
    "  --version                 show the version\n"
    "\n"
    "When ready it prints one line, \"listening on HOST:PORT\", on stdout; its log\n"
    "goes to stderr, a line per event with a UTC time and a level.\n"
    "SIGINT or SIGTERM: clients get bye, sessions are closed, the collision log is\n"
    "written out and the database closed.\n"
    "\n"
    "Files:\n"
    "  FILE, FILE-wal, FILE-shm  the database (--db) in SQLite's WAL mode; read it\n"
    "                            with cvre-admin (also while the server runs), copy\n"
    "                            it with cvre-admin backup, never with cp\n"
    "  cvre-import               the importer, beside cvre-server unless --importer\n"
    "\n"
    "Exit status: 0 stopped by a signal, 1 could not start (the message says why)\n"
    "or a fatal error, 2 bad flags.\n";

/* Parses a number in [lo, hi] or exits with a message naming the flag. */
static double number(const char *flag, const char *text, double lo, double hi)
{
    double v;
    if (num_parse_real(text, lo, hi, &v) < 0) {
        fprintf(stderr, "cvre-server: --%s wants a number from %g to %g, not \"%s\"\n", flag, lo, hi, text);
        exit(2);
    }
    return v;
}

static double integer(const char *flag, const char *text, double lo, double hi)
{
    double v = number(flag, text, lo, hi);
    if (v != floor(v)) {
        fprintf(stderr, "cvre-server: --%s wants a whole number, not \"%s\"\n", flag, text);
        exit(2);
    }
    return v;
}

/* Splits text, HOST:PORT or [IPV6]:PORT, in place into *host and *port,
 * or exits with a message naming the flag. */
static void host_port(const char *flag, char *text, const char **host, uint16_t *port)
{
    char *colon = strrchr(text, ':');
    size_t hlen = colon ? (size_t)(colon - text) : 0;
    int bracketed = hlen >= 2 && text[0] == '[' && text[hlen - 1] == ']';
    if (!colon || hlen == 0 || (text[0] == '[' && !bracketed) || (bracketed && hlen == 2)) {
        fprintf(stderr, "cvre-server: --%s wants HOST:PORT or [IPV6]:PORT, not \"%s\"\n", flag, text);
        exit(2);
    }
    *port = (uint16_t)integer(flag, colon + 1, 0, 65535);
    *colon = 0;
    if (bracketed) {
        text[hlen - 1] = 0;
        text++;
    }
    *host = text;
}

/* Lifts the soft limit on open files to the hard one: each client is a file. */
static void raise_fd_limit(uint32_t max_clients)
{
    struct rlimit rl;
    if (getrlimit(RLIMIT_NOFILE, &rl) != 0)
        return;
    rl.rlim_cur = rl.rlim_max;
    setrlimit(RLIMIT_NOFILE, &rl);
    if (getrlimit(RLIMIT_NOFILE, &rl) == 0 && rl.rlim_cur < (rlim_t)max_clients + 64)
        log_warn("open-file limit %llu is below --max-clients %u; connections past it will be refused",
                 (unsigned long long)rl.rlim_cur, max_clients);
}

int main(int argc, char **argv)
{
    enum { O_HOST = 256, O_PORT, O_DB, O_TICK, O_MAXC, O_AOI, O_SPEED, O_WORLD, O_SPAWN, O_HS, O_IDLE, O_SEED,
           O_STATS, O_STATS_INT, O_LOG, O_HELP, O_VERSION, O_WORLD_FILE, O_MAX_UPLOAD, O_MAX_TRIS, O_R_INT,
           O_R_EPS, O_R_MINP, O_R_MINU, O_R_DEPTH, O_R_BOXES, O_R_EMPTY, O_R_THREADS, O_IMPORTER, O_IMP_MEM, O_IMP_CPU, O_AUTH, O_LOGIN_BURST, O_PER_ADDR, O_JOINS, O_Q_OBJ, O_Q_MB, O_METRICS, O_WEB, O_WEB_ROOT, O_WEB_ORIGIN };
    static const struct option opts[] = {
        {"host", required_argument, 0, O_HOST}, {"port", required_argument, 0, O_PORT},
        {"db", required_argument, 0, O_DB}, {"tick-hz", required_argument, 0, O_TICK},
        {"max-clients", required_argument, 0, O_MAXC}, {"aoi-radius", required_argument, 0, O_AOI},
        {"max-speed", required_argument, 0, O_SPEED}, {"world-size", required_argument, 0, O_WORLD},
        {"spawn-radius", required_argument, 0, O_SPAWN}, {"handshake-timeout", required_argument, 0, O_HS},
        {"idle-timeout", required_argument, 0, O_IDLE}, {"seed", required_argument, 0, O_SEED},
        {"stats-file", required_argument, 0, O_STATS}, {"stats-interval", required_argument, 0, O_STATS_INT},
        {"log-level", required_argument, 0, O_LOG}, {"help", no_argument, 0, O_HELP},
        {"version", no_argument, 0, O_VERSION}, {"world", required_argument, 0, O_WORLD_FILE},
        {"max-upload", required_argument, 0, O_MAX_UPLOAD}, {"max-triangles", required_argument, 0, O_MAX_TRIS},
        {"refine-interval", required_argument, 0, O_R_INT}, {"refine-eps", required_argument, 0, O_R_EPS},
        {"refine-min-points", required_argument, 0, O_R_MINP}, {"refine-min-users", required_argument, 0, O_R_MINU},
        {"refine-depth", required_argument, 0, O_R_DEPTH}, {"refine-max-boxes", required_argument, 0, O_R_BOXES},
        {"refine-max-empty", required_argument, 0, O_R_EMPTY}, {"refine-threads", required_argument, 0, O_R_THREADS},
        {"importer", required_argument, 0, O_IMPORTER},
        {"import-memory", required_argument, 0, O_IMP_MEM}, {"import-cpu", required_argument, 0, O_IMP_CPU},
        {"auth", required_argument, 0, O_AUTH}, {"login-burst", required_argument, 0, O_LOGIN_BURST},
        {"max-per-address", required_argument, 0, O_PER_ADDR}, {"joins-per-second", required_argument, 0, O_JOINS},
        {"quota-objects", required_argument, 0, O_Q_OBJ}, {"quota-mb", required_argument, 0, O_Q_MB},
        {"metrics", required_argument, 0, O_METRICS},
        {"web", required_argument, 0, O_WEB}, {"web-root", required_argument, 0, O_WEB_ROOT},
        {"web-origin", required_argument, 0, O_WEB_ORIGIN},
        {0, 0, 0, 0}};
    server_config cfg;
    server_config_defaults(&cfg);
    int o;
    cvre_alloc_keep_freed(); /* it refines (alloc.h) */
    while ((o = getopt_long(argc, argv, "", opts, NULL)) != -1) {
        switch (o) {
        case O_HOST: cfg.host = optarg; break;
        case O_PORT: cfg.port = (uint16_t)integer("port", optarg, 0, 65535); break;
        case O_DB: cfg.db_path = optarg; break;
        case O_TICK: cfg.tick_hz = (int)integer("tick-hz", optarg, SRV_TICK_HZ_MIN, SRV_TICK_HZ_MAX); break;
        case O_MAXC: cfg.max_clients = (uint32_t)integer("max-clients", optarg, 1, SRV_MAX_CLIENTS_LIMIT); break;
        case O_AOI: cfg.aoi_radius = (float)number("aoi-radius", optarg, 1, SRV_AOI_RADIUS_MAX); break;
        case O_SPEED: cfg.max_speed = (float)number("max-speed", optarg, 0.1, SRV_MAX_SPEED_LIMIT); break;
        case O_WORLD:
            cfg.world_size = (float)number("world-size", optarg, SRV_WORLD_SIZE_MIN, SRV_WORLD_SIZE_MAX);
            break;
        case O_SPAWN: cfg.spawn_radius = (float)number("spawn-radius", optarg, 0, SRV_WORLD_SIZE_MAX / 2); break;
        case O_HS: cfg.handshake_timeout_ms = (uint32_t)integer("handshake-timeout", optarg, 10, 3600000); break;
        case O_IDLE: cfg.idle_timeout_ms = (uint32_t)integer("idle-timeout", optarg, 10, 86400000); break;
        case O_SEED: cfg.seed = (uint64_t)integer("seed", optarg, 0, 9007199254740992.0); break;
        case O_STATS: cfg.stats_file = optarg; break;
        case O_METRICS: host_port("metrics", optarg, &cfg.metrics_host, &cfg.metrics_port); break;
        case O_WEB: host_port("web", optarg, &cfg.web_host, &cfg.web_port); break;
        case O_WEB_ROOT: cfg.web_root = optarg; break;
        case O_WEB_ORIGIN: cfg.web_origins = optarg; break;
        case O_WORLD_FILE: cfg.world_file = optarg; break;
        case O_MAX_UPLOAD: cfg.max_upload = (uint32_t)integer("max-upload", optarg, 1, SRV_MAX_UPLOAD_LIMIT); break;
        case O_MAX_TRIS: cfg.max_triangles = (uint32_t)integer("max-triangles", optarg, 1, SRV_MAX_TRIANGLES_LIMIT); break;
        case O_IMPORTER: cfg.importer.helper = optarg; break;
        case O_LOGIN_BURST: cfg.login_burst = integer("login-burst", optarg, 1, 1000000); break;
        case O_Q_OBJ: cfg.quota_objects = (uint32_t)integer("quota-objects", optarg, 0, 100000000); break;
        case O_Q_MB: cfg.quota_bytes = (uint64_t)integer("quota-mb", optarg, 0, 1048576) << 20; break;
        case O_PER_ADDR: cfg.max_per_address = (uint32_t)integer("max-per-address", optarg, 0, 1000000); break;
        case O_JOINS: cfg.joins_per_second = number("joins-per-second", optarg, 0, 1000000); break;
        case O_AUTH:
            if (strcmp(optarg, "required") != 0 && strcmp(optarg, "guests") != 0) {
                fprintf(stderr, "cvre-server: --auth wants required or guests, not \"%s\"\n", optarg);
                return 2;
            }
            cfg.auth_required = strcmp(optarg, "required") == 0;
            break;
        case O_IMP_MEM: cfg.importer.memory_mb = (uint32_t)integer("import-memory", optarg, 256, 1048576); break;
        case O_IMP_CPU: cfg.importer.cpu_seconds = (uint32_t)integer("import-cpu", optarg, 1, 86400); break;
        case O_R_INT: cfg.refine_interval_s = number("refine-interval", optarg, 0, 86400); break;
        case O_R_EPS: cfg.refine_eps = number("refine-eps", optarg, 0.001, 1000); break;
        case O_R_MINP: cfg.refine_min_points = (uint32_t)integer("refine-min-points", optarg, 1, 1000000); break;
        case O_R_MINU: cfg.refine_min_users = (uint32_t)integer("refine-min-users", optarg, 1, 1000000); break;
        case O_R_DEPTH:
            cfg.refine_depth = (uint32_t)integer("refine-depth", optarg, ECM_DEPTH_MIN, ECM_DEPTH_MAX);
            break;
        case O_R_BOXES:
            cfg.refine_max_boxes = (uint32_t)integer("refine-max-boxes", optarg, 1, ECM_MAX_BOXES_LIMIT);
            break;
        case O_R_EMPTY: cfg.refine_max_empty = number("refine-max-empty", optarg, 0, 1); break;
        case O_R_THREADS:
            cfg.refine_threads = (uint32_t)integer("refine-threads", optarg, 0, VOXEL_MAX_THREADS);
            break;
        case O_STATS_INT: cfg.stats_interval_ms = (uint32_t)(number("stats-interval", optarg, 0.1, 86400) * 1000); break;
        case O_LOG: {
            int level = log_parse_level(optarg);
            if (level < 0) {
                fprintf(stderr, "cvre-server: --log-level wants debug, info, warn, error or off, not \"%s\"\n", optarg);
                return 2;
            }
            log_set_level(level);
            break;
        }
        case O_HELP: fputs(usage, stdout); return 0;
        case O_VERSION: printf("cvre-server %s (protocol %d)\n", CVRE_VERSION, PROTO_VERSION); return 0;
        default: fputs("cvre-server: try --help\n", stderr); return 2;
        }
    }
    if (optind < argc) {
        fprintf(stderr, "cvre-server: unexpected argument \"%s\"; try --help\n", argv[optind]);
        return 2;
    }
    if (cfg.spawn_radius > cfg.world_size * 0.5f) {
        fprintf(stderr, "cvre-server: --spawn-radius %g reaches past the world's edge: at most half of --world-size %g\n",
                (double)cfg.spawn_radius, (double)cfg.world_size);
        return 2;
    }
    raise_fd_limit(cfg.max_clients);
    char err[512];
    server *s = server_create(&cfg, err, sizeof err);
    if (!s) {
        log_error("cannot start: %s", err);
        return 1;
    }
    printf("listening on %s\n", server_address(s));
    fflush(stdout);
    int rc = server_run(s);
    server_destroy(s);
    return rc == 0 ? 0 : 1;
}
