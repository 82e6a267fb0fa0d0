/*
 * server.c: cvre-server's lifecycle (server.h): creating the server and
 * everything it runs on one loop, the housekeeping between ticks
 * (timeouts, the admin feed), freeing closed clients at a safe point,
 * and the shutdown that says bye to every client. The rest of the work is
 * in the files serverInt.h lists; this one calls them and none calls it.
 */
#include "server.h"

#include <errno.h>
#include <signal.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <strings.h>
#include <sys/signalfd.h>
#include <unistd.h>

#include "admission.h"
#include "alloc.h"
#include "clients.h"
#include "err.h"
#include "handlers.h"
#include "log.h"
#include "metrics_endpoint.h"
#include "web_endpoint.h"
#include "moderation.h"
#include "objects.h"
#include "record.h"
#include "refine.h"
#include "serverInt.h"
#include "session_log.h"
#include "srv_limits.h"
#include "stats.h"
#include "tick.h"

/* How often timeouts and slow readers are checked. */
#define HOUSEKEEPING_MS 100u
/* How long a shutdown waits for clients to take their bye. */
#define SHUTDOWN_GRACE_MS 2000u


void server_config_defaults(server_config *cfg)
{
    *cfg = (server_config){
        .host = "127.0.0.1",
        .port = 7878,
        .db_path = "cvre.db",
        .tick_hz = SRV_TICK_HZ_DEFAULT,
        .max_clients = SRV_MAX_CLIENTS_DEFAULT,
        .aoi_radius = SRV_AOI_RADIUS_DEFAULT,
        .max_speed = SRV_MAX_SPEED_DEFAULT,
        .world_size = SRV_WORLD_SIZE_DEFAULT,
        .spawn_radius = SRV_SPAWN_RADIUS_DEFAULT,
        .handshake_timeout_ms = SRV_HANDSHAKE_TIMEOUT_MS,
        .idle_timeout_ms = SRV_IDLE_TIMEOUT_MS,
        .seed = 1,
        .stats_file = NULL,
        .stats_interval_ms = 10000,
        .web_root = "client/web",
        .max_upload = SRV_MAX_UPLOAD_DEFAULT,
        .max_triangles = SRV_MAX_TRIANGLES_DEFAULT,
        .world_file = NULL,
        .importer = {import_proc_default_helper(), IMPORT_PROC_MEMORY_MB, IMPORT_PROC_CPU_SECONDS},
        .login_burst = SRV_LOGIN_BURST,
        .max_per_address = SRV_MAX_PER_ADDRESS_DEFAULT,
        .quota_objects = SRV_QUOTA_OBJECTS_DEFAULT,
        .quota_bytes = (uint64_t)SRV_QUOTA_MB_DEFAULT << 20,
        .joins_per_second = SRV_JOINS_PER_SECOND_DEFAULT,
        .refine_interval_s = SRV_REFINE_INTERVAL_DEFAULT,
        .refine_eps = CLUSTER_EPS_DEFAULT,
        .refine_min_points = CLUSTER_MIN_POINTS_DEFAULT,
        .refine_min_users = CLUSTER_MIN_USERS_DEFAULT,
        .refine_depth = ECM_DEPTH_DEFAULT,
        .refine_max_boxes = ECM_MAX_BOXES_DEFAULT,
        .refine_max_empty = ECM_MAX_EMPTY_DEFAULT,
        .refine_threads = 0,
    };
}

const char *server_address(const server *s) { return s->address; }

/* Frees c with what it held: its upload and object view, its avatar, its
 * session (closed in the store with its reason). Called only at safe
 * points, outside any of c's callbacks. */
static void reap(server *s, client *c)
{
    objects__client_gone(s, c);
    if (c->avatar_id) {
        world_remove(s->world, c->avatar_id);
        s->by_slot[world_slot(c->avatar_id)] = NULL;
    }
    if (c->session_id) {
        store_event *e = session_log__push(s, EVT_CLOSE, c->session_id);
        snprintf(e->text, sizeof e->text, "%s", c->end_reason[0] ? c->end_reason : "closed");
        log_info("%s (session %lld) ended: %s", c->peer, (long long)c->session_id, e->text);
    }
    clients__free(s, c);
}

/* ---- shutdown --------------------------------------------------------- */

/* Says bye (reason) to c and closes it; why goes to the session record. */
static void say_bye(server *s, client *c, uint8_t reason, const char *why)
{
    proto_writer w;
    if (c->closing || clients__out_begin(s, c, PROTO_SIZE_BYE, &w) < 0)
        return;
    proto_put_bye(&w, reason);
    clients__out_end(s, c, &w);
    clients__begin_close(s, c, why);
}

static void begin_shutdown(server *s, const char *why)
{
    log_info("%s: shutting down, saying bye to %u clients", why, s->nclients);
    s->stopping = 1;
    s->stop_deadline_ns = server__now(s) + SHUTDOWN_GRACE_MS * NS_PER_MS;
    admission__stop(s);
    web__stop(s);
    for (uint32_t i = 0; i < s->nclients; i++)
        say_bye(s, s->clients[i], PROTO_BYE_SHUTDOWN, "shutdown");
}

/* One admin action from the store's feed: a kick ends one session; a ban
 * every session joined under the name (the auth worker refuses its joins
 * from now on), a new password or a deleted account that account's
 * sessions (and a deleted account's objects pass to the world). */
static void on_admin_event(void *ctx, const char *kind, int64_t session_id, const char *name)
{
    static const struct {
        const char *kind, *why;
    } ends[] = {{"kick", "kicked"}, {"ban", "banned"}, {"logout", "logged out: the password changed"},
                {"deleted", "the account was deleted"}};
    server *s = ctx;
    size_t k = 0;
    while (k < sizeof ends / sizeof ends[0] && strcmp(kind, ends[k].kind) != 0)
        k++;
    if (k == sizeof ends / sizeof ends[0]) {
        log_info("admin: %s %s", kind, name);
        return;
    }
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *c = s->clients[i];
        const world_avatar *a = c->avatar_id ? world_get(s->world, c->avatar_id) : NULL;
        /* a join being checked may have passed the ban check already */
        const char *who = a ? a->name : c->state == ST_AUTH ? c->join_name : NULL;
        if (k == 0 ? c->session_id != session_id : !(who && strcasecmp(who, name) == 0))
            continue;
        log_info("%s (session %lld): %s", c->peer, (long long)c->session_id, ends[k].why);
        say_bye(s, c, PROTO_BYE_KICKED, ends[k].why);
    }
    if (strcmp(kind, "deleted") == 0)
        objects__owner_gone(s, name);
}

/* Enforces the handshake, idle and linger timeouts and the soft output
 * limit; runs every HOUSEKEEPING_MS. */
static void on_housekeeping(ev_loop *loop, void *data)
{
    (void)loop;
    server *s = data;
    uint64_t now = server__now(s);
    if (db_admin_events(s->db, s->admin_feed_last, on_admin_event, s, &s->admin_feed_last) < 0 && !db_busy(s->db))
        log_warn("admin feed: %s", db_error(s->db));
    for (uint32_t i = 0; i < s->nclients; i++) {
        client *c = s->clients[i];
        if (c->dead)
            continue;
        int overdue = conn_overdue(&c->c); /* the linger, or the soft output limit */
        if (c->closing) {
            if (overdue == -ETIMEDOUT)
                c->dead = 1;
        } else if (c->state != ST_JOINED && now - c->connected_ns > s->cfg.handshake_timeout_ms * NS_PER_MS) {
            clients__protocol_error(s, c, PROTO_ERR_TIMEOUT, "handshake not completed within %u ms",
                           s->cfg.handshake_timeout_ms);
        } else if (now - c->last_frame_ns > s->cfg.idle_timeout_ms * NS_PER_MS) {
            clients__protocol_error(s, c, PROTO_ERR_TIMEOUT, "no complete frame for %u ms", s->cfg.idle_timeout_ms);
        } else if (overdue == -ENOBUFS) {
            s->st.slow_readers++;
            clients__kill(s, c, "output backlog over %u bytes for %u ms", SRV_OUTBUF_SOFT, SRV_OUTBUF_SOFT_MS);
        }
    }
}

static void on_signal(ev_loop *loop, int fd, unsigned events, void *data)
{
    (void)loop;
    (void)events;
    server *s = data;
    struct signalfd_siginfo si;
    if (read(fd, &si, sizeof si) != (ssize_t)sizeof si || s->stopping)
        return;
    begin_shutdown(s, si.ssi_signo == SIGINT ? "SIGINT" : "SIGTERM");
}

/* Housekeeping before the loop sleeps: write what the tick and the handlers
 * queued (one write per client per wake-up), then free the clients that were
 * closed, outside any of their callbacks. */
static void before_sleep(ev_loop *loop, void *data)
{
    server *s = data;
    for (uint32_t i = 0; i < s->nwrite; i++) {
        s->write_list[i]->in_write_list = 0;
        clients__flush(s, s->write_list[i]);
    }
    s->nwrite = 0;
    for (uint32_t i = 0; i < s->nclients;) {
        client *c = s->clients[i];
        if (c->dead)
            reap(s, c); /* moves the last client into slot i */
        else
            i++;
    }
    if (s->stopping && (s->nclients == 0 || server__now(s) > s->stop_deadline_ns))
        ev_stop(loop);
}

/* ---- setup ------------------------------------------------------------ */

static int setup_signals(server *s, char *err, size_t errlen)
{
    sigset_t set;
    sigemptyset(&set);
    sigaddset(&set, SIGINT);
    sigaddset(&set, SIGTERM);
    signal(SIGPIPE, SIG_IGN);
    if (sigprocmask(SIG_BLOCK, &set, NULL) < 0 || (s->signal_fd = signalfd(-1, &set, SFD_NONBLOCK | SFD_CLOEXEC)) < 0)
        return cvre_fail(err, errlen, -errno, "signalfd: %s", strerror(errno));
    return 0;
}

server *server_create(const server_config *cfg, char *err, size_t errlen)
{
    server *s = cvre_xcalloc(1, sizeof *s);
    s->cfg = *cfg;
    s->signal_fd = -1;
    s->web_root_fd = -1;
    /* fds are handed out lowest first, so this bounds every client fd. */
    s->max_fd = (int)cfg->max_clients + 64;
    float half = cfg->world_size * 0.5f;
    world_config wc = {.min = {-half, 0, -half}, .max = {half, SRV_WORLD_HEIGHT, half},
                       .max_speed = cfg->max_speed, .aoi_radius = cfg->aoi_radius,
                       .spawn_radius = cfg->spawn_radius, .tick_dt = 1.0f / (float)cfg->tick_hz,
                       .capacity = cfg->max_clients, .seed = cfg->seed};
    s->world = world_create(&wc);
    if (!s->world) {
        snprintf(err, errlen, "cannot create the world (out of memory?)");
        goto fail;
    }
    s->clients = cvre_xcalloc(cfg->max_clients, sizeof *s->clients);
    s->write_list = cvre_xcalloc(cfg->max_clients, sizeof *s->write_list);
    s->vis = cvre_xcalloc(SRV_AOI_MAX, sizeof *s->vis);
    s->joined = cvre_xcalloc(SRV_AOI_MAX, sizeof *s->joined);
    s->snap = cvre_xcalloc(SRV_AOI_MAX, sizeof *s->snap);
    s->left = cvre_xcalloc(cfg->max_clients, sizeof *s->left);
    s->by_slot = cvre_xcalloc(cfg->max_clients, sizeof *s->by_slot);
    s->mark_id = cvre_xcalloc(cfg->max_clients, sizeof *s->mark_id);
    s->mark_stamp = cvre_xcalloc(cfg->max_clients, sizeof *s->mark_stamp);
    s->st.tick_cap = (uint32_t)cfg->tick_hz * (cfg->stats_interval_ms / 1000u + 1u) * 2u;
    s->st.tick_us = cvre_xcalloc(s->st.tick_cap, sizeof *s->st.tick_us);

    s->db = db_open(cfg->db_path, DB_READWRITE, err, errlen);
    if (!s->db)
        goto fail;
    s->last_session_id = db_session_last_id(s->db);
    int stale = db_sessions_close_stale(s->db, db_now());
    if (s->last_session_id < 0 || stale < 0) {
        snprintf(err, errlen, "database %s: %s", cfg->db_path, db_error(s->db));
        goto fail;
    }
    if (stale)
        log_warn("closed %d sessions left open by a previous run that did not shut down cleanly", stale);

    s->loop = ev_create(s->max_fd);
    if (!s->loop) {
        snprintf(err, errlen, "event loop: %s", strerror(errno));
        goto fail;
    }
    /* Signals are blocked before any thread starts, so that every thread
     * inherits the mask and SIGINT/SIGTERM reach only the signalfd. */
    if (setup_signals(s, err, errlen) < 0)
        goto fail;
    dblog_config lc = {DBLOG_QUEUE_ROWS_DEFAULT, DBLOG_BATCH_ROWS_DEFAULT, DBLOG_BATCH_MS_DEFAULT};
    s->log = dblog_open(cfg->db_path, &lc, err, errlen);
    if (!s->log || objects__start(s, err, errlen) < 0)
        goto fail;
    if (admission__start(s, err, errlen) < 0)
        goto fail;
    s->logins = ratelimit_create(SRV_LOGIN_SLOTS, SRV_LOGIN_PER_SECOND, cfg->login_burst);
    s->per_address = addrcount_create(SRV_LOGIN_SLOTS);
    if (cfg->joins_per_second > 0)
        s->joins = ratelimit_create(SRV_LOGIN_SLOTS, cfg->joins_per_second, 2 * cfg->joins_per_second);
    if (db_admin_events_head(s->db, &s->admin_feed_last) < 0) {
        snprintf(err, errlen, "database %s: %s", cfg->db_path, db_error(s->db));
        goto fail;
    }
    s->auth = auth_start(cfg->db_path, err, errlen);
    if (!s->logins || !s->per_address || (cfg->joins_per_second > 0 && !s->joins) || !s->auth)
        goto fail;
    /* From now on this connection is the tick's: it must never wait. */
    db_set_busy_timeout(s->db, 0);
    uint64_t tick_ns = (uint64_t)1000000000 / (uint64_t)cfg->tick_hz;
    if (ev_io_add(s->loop, s->signal_fd, EV_READ, on_signal, s) < 0 ||
        ev_io_add(s->loop, auth_fd(s->auth), EV_READ, handlers__on_auth_results, s) < 0 ||
        ev_timer_start(s->loop, tick_ns, tick_ns, tick__run, s) < 0 ||
        ev_timer_start(s->loop, HOUSEKEEPING_MS * NS_PER_MS, HOUSEKEEPING_MS * NS_PER_MS, on_housekeeping, s) < 0 ||
        ev_timer_start(s->loop, cfg->stats_interval_ms * NS_PER_MS, cfg->stats_interval_ms * NS_PER_MS, stats__report,
                       s) < 0) {
        snprintf(err, errlen, "event loop setup failed");
        goto fail;
    }
    if (metrics__start(s, err, errlen) < 0 || web__start(s, err, errlen) < 0)
        goto fail;
    ev_set_before_sleep(s->loop, before_sleep, s);
    s->st.interval_start_ns = ev_clock(s->loop);
    return s;
fail:
    server_destroy(s);
    return NULL;
}

int server_run(server *s)
{
    log_info("serving on %s: tick %d Hz, world %.0f m, area of interest %.0f m, up to %u clients", s->address,
             s->cfg.tick_hz, (double)s->cfg.world_size, (double)s->cfg.aoi_radius, s->cfg.max_clients);
    int rc = ev_run(s->loop);
    if (rc < 0)
        log_error("event loop: %s", strerror(-rc));
    for (uint32_t i = 0; i < s->nclients; i++)
        if (!s->clients[i]->end_reason[0] || !s->stopping)
            snprintf(s->clients[i]->end_reason, sizeof s->clients[i]->end_reason, "shutdown");
    while (s->nclients)
        reap(s, s->clients[0]);
    db_set_busy_timeout(s->db, SRV_DB_BUSY_SHUTDOWN_MS); /* the last flush may wait */
    session_log__flush(s);
    dblog_stats ls;
    dblog_stop(s->log, &ls);
    s->log = NULL;
    log_info("stopped: %llu connections served; collision log: %llu rows written, %llu dropped, %llu lost",
             (unsigned long long)s->st.accepted, (unsigned long long)ls.written, (unsigned long long)ls.dropped,
             (unsigned long long)ls.lost);
    return rc < 0 ? rc : 0;
}

void server_destroy(server *s)
{
    if (!s)
        return;
    while (s->nclients)
        reap(s, s->clients[0]);
    objects__stop(s);
    auth_stop(s->auth);
    ratelimit_destroy(s->logins);
    ratelimit_destroy(s->joins);
    addrcount_destroy(s->per_address);
    if (s->log)
        dblog_stop(s->log, NULL);
    metrics__stop(s);
    web__stop(s);
    admission__stop(s);
    if (s->loop)
        ev_destroy(s->loop);
    if (s->signal_fd >= 0)
        close(s->signal_fd);
    db_close(s->db);
    world_destroy(s->world);
    free(s->clients);
    free(s->write_list);
    free(s->vis);
    free(s->joined);
    free(s->snap);
    free(s->left);
    free(s->by_slot);
    free(s->mark_id);
    free(s->mark_stamp);
    free(s->events);
    free(s->st.tick_us);
    free(s);
}
