/* bots.c: the bot swarm (see bots.h). */
#include "bots.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include "alloc.h"
#include "events.h"
#include "log.h"

#define NS_PER_S 1000000000ull
#define PI 3.14159265358979323846

/* The scheduler's resolution: every millisecond it starts the connections
 * the ramp allows and sends the moves that are due. At 20 Hz that splits a
 * period into 50 slots, smooth enough for the server and cheap for us. */
#define BOTS_TICK_NS 1000000ull
#define BOTS_STATS_NS NS_PER_S
/* After the byes, how long the server gets to close before the summary. */
#define BOTS_LINGER_NS NS_PER_S

/* Bots walk below the speed limit so that timing jitter on either side
 * rarely gets a move clamped. */
#define BOTS_SPEED_FRACTION 0.8
#define BOTS_TURN_NS NS_PER_S  /* random walk: heading changes once a second */
#define BOTS_TURN_MAX (PI / 6) /* by up to 30 degrees either way */
#define BOTS_MARGIN_M 1.0      /* reflect this far inside the world bounds */
#define BOTS_CIRCLE_M 10.0     /* circle radius around the spawn point */
/* Raw bots get no welcome, so they assume a speed and a world. */
#define BOTS_RAW_SPEED 4.0
#define BOTS_RAW_HALF 500.0

/* Over a WebSocket, upgrades in flight at once, at most: the server's web
 * endpoint answers 64 HTTP connections at a time and refuses more with 503
 * (WEB_CONNS, server/web_endpoint.c), and a ramp of hundreds a second on a
 * busy machine would have more than that waiting; 8 leaves room for several
 * swarms side by side and for browsers. The ramp waits for a place. */
#define BOTS_UPGRADES_MAX 8u

/* Moves remembered per bot to reconcile with the server: 32 at 20 Hz is
 * 1.6 s in flight, far beyond a healthy round trip; past it a bot simply
 * jumps to the authoritative position. A power of two. */
#define BOTS_RING 32u
_Static_assert((BOTS_RING & (BOTS_RING - 1)) == 0, "BOTS_RING is a power of two");

/* Where a bot is going; copied, advanced, and kept only if the move was
 * sent, so a dropped move leaves no trace. */
typedef struct walker {
    float pos[3];     /* last point sent, corrected by the server */
    double angle;     /* heading (random walk) or place on the circle */
    double radius;    /* circle: distance from the centre, grows to BOTS_CIRCLE_M */
    uint64_t turn_at; /* random walk: next heading change */
} walker;

typedef struct bot {
    bots *swarm;
    session *c; /* NULL before its start and after its end */
    unsigned idx;
    walker w;
    float centre[3]; /* spawn point */
    uint32_t last_seq;
    float sent[BOTS_RING][3]; /* points sent, by seq % BOTS_RING */
} bot;

struct bots {
    ev_loop *loop;
    session_ctx *ctx;
    bots_opts o;
    bot *bot;
    unsigned started;
    unsigned open; /* started and not yet closed */
    unsigned upgrading[BOTS_UPGRADES_MAX]; /* --ws: bots whose upgrade may be in flight */
    unsigned nupgrading;
    uint64_t t0;
    uint64_t period_ns;
    /* The next due move is bot[cursor]'s in the period that began at
     * cycle_at; bot i's slot is i/count of the way through a period. */
    unsigned cursor;
    uint64_t cycle_at;
    int tick_timer, stats_timer, end_timer, linger_timer;
    int ending, finished;
    events_counts k;
    uint64_t rng;
};

/* xorshift64*: fast, and statistically plenty for wandering bots. */
static double rand_unit(bots *b)
{
    b->rng ^= b->rng >> 12;
    b->rng ^= b->rng << 25;
    b->rng ^= b->rng >> 27;
    return (double)((b->rng * 2685821657736338717ull) >> 11) * (1.0 / 9007199254740992.0);
}

/* ---- movement ---------------------------------------------------------- */

/* Folds v back into [lo, hi] like a ball off a wall; returns 1 if it
 * bounced, so the heading can turn. A world narrower than the margins pins
 * the bot to the middle. */
static int reflect(double *v, double lo, double hi)
{
    if (lo > hi) {
        *v = (lo + hi) / 2;
        return 0;
    }
    int bounced = 0;
    if (*v < lo) {
        *v = 2 * lo - *v;
        bounced = 1;
    } else if (*v > hi) {
        *v = 2 * hi - *v;
        bounced = 1;
    }
    if (*v < lo)
        *v = lo;
    if (*v > hi)
        *v = hi;
    return bounced;
}

static void random_walk(bots *b, walker *w, double step, const float lo[3], const float hi[3],
                        uint64_t now)
{
    if (now >= w->turn_at) {
        w->angle += (2 * rand_unit(b) - 1) * BOTS_TURN_MAX;
        w->turn_at = now + BOTS_TURN_NS;
    }
    double x = w->pos[0] + step * cos(w->angle);
    double z = w->pos[2] + step * sin(w->angle);
    if (reflect(&x, lo[0] + BOTS_MARGIN_M, hi[0] - BOTS_MARGIN_M))
        w->angle = PI - w->angle;
    if (reflect(&z, lo[2] + BOTS_MARGIN_M, hi[2] - BOTS_MARGIN_M))
        w->angle = -w->angle;
    w->pos[0] = (float)x;
    w->pos[2] = (float)z;
}

/* Walks out from the centre to the circle, then around it. */
static void circle(walker *w, double step, const float centre[3])
{
    if (w->radius < BOTS_CIRCLE_M)
        w->radius = fmin(BOTS_CIRCLE_M, w->radius + step);
    else
        w->angle += step / BOTS_CIRCLE_M;
    w->pos[0] = (float)(centre[0] + w->radius * cos(w->angle));
    w->pos[1] = centre[1];
    w->pos[2] = (float)(centre[2] + w->radius * sin(w->angle));
}

/* Sends bot t's next move if it is in a state to move. */
static void serve(bots *b, bot *t, uint64_t now)
{
    if (!t->c)
        return;
    int st = session_state(t->c);
    if (st != SESSION_JOINED && st != SESSION_RAW)
        return;
    static const float raw_lo[3] = {-BOTS_RAW_HALF, 0, -BOTS_RAW_HALF};
    static const float raw_hi[3] = {BOTS_RAW_HALF, 0, BOTS_RAW_HALF};
    const proto_welcome *wel = &session_get_view(t->c)->welcome;
    double speed = st == SESSION_RAW ? BOTS_RAW_SPEED : wel->max_speed;
    double step = BOTS_SPEED_FRACTION * speed / b->o.rate;
    walker w = t->w;
    if (b->o.pattern == BOTS_CIRCLE && st == SESSION_JOINED)
        circle(&w, step, t->centre);
    else if (st == SESSION_RAW)
        random_walk(b, &w, step, raw_lo, raw_hi, now);
    else
        random_walk(b, &w, step, wel->world_min, wel->world_max, now);
    /* Facing the way it walks (yaw 0 looks down -z), head level. */
    float dx = w.pos[0] - t->w.pos[0], dz = w.pos[2] - t->w.pos[2];
    if (b->o.pose && st == SESSION_JOINED && (dx != 0.0f || dz != 0.0f))
        session_set_facing(t->c, atan2f(-dx, -dz), 0.0f, 1);
    uint32_t seq = session_send_move(t->c, w.pos);
    if (!seq) {
        b->k.moves_dropped++;
        return;
    }
    b->k.moves_sent++;
    t->w = w;
    t->last_seq = seq;
    memcpy(t->sent[seq % BOTS_RING], w.pos, sizeof w.pos);
}

/*
 * Adopts the server's word on our position without walking backwards: the
 * snapshot says where the move acked by it left us, and the moves sent since
 * are still on their way. So the difference between the authoritative
 * position and what we had asked for at that seq (zero unless the server
 * clamped or blocked us) shifts those later moves and the current position.
 */
static void reconcile(bot *t, const session_view *v)
{
    uint32_t ack = v->ack;
    if (ack == 0)
        return; /* no move applied yet: the position is the spawn we started from */
    if (ack > t->last_seq || t->last_seq - ack >= BOTS_RING) {
        memcpy(t->w.pos, v->pos, sizeof t->w.pos);
        return;
    }
    float *asked = t->sent[ack % BOTS_RING];
    float d[3] = {v->pos[0] - asked[0], v->pos[1] - asked[1], v->pos[2] - asked[2]};
    if (d[0] * d[0] + d[1] * d[1] + d[2] * d[2] < 1e-6f)
        return;
    for (uint32_t s = ack; s != t->last_seq + 1; s++)
        for (int i = 0; i < 3; i++)
            t->sent[s % BOTS_RING][i] += d[i];
    for (int i = 0; i < 3; i++)
        t->w.pos[i] += d[i];
}

/* ---- connections ------------------------------------------------------- */

static void on_msg(session *c, const proto_msg *m, void *data)
{
    bot *t = data;
    bots *b = t->swarm;
    const session_view *v = session_get_view(c);
    switch (m->type) {
    case PROTO_JOIN_OK:
        b->k.joined++;
        memcpy(t->w.pos, v->pos, sizeof t->w.pos);
        memcpy(t->centre, v->pos, sizeof t->centre);
        t->w.angle = 2 * PI * rand_unit(b);
        t->w.turn_at = ev_now(b->loop) + BOTS_TURN_NS;
        break;
    case PROTO_SNAPSHOT:
        if (v->pos_fresh)
            reconcile(t, v);
        break;
    case PROTO_ERROR:
        b->k.errors++;
        events_error((int)t->idx, m->u.error.code, m->u.error.message.ptr, m->u.error.message.len);
        break;
    case PROTO_BYE:
        if (!b->ending)
            events_bye((int)t->idx, m->u.bye.reason);
        break;
    case PROTO_COLLISION:
        b->k.collisions++;
        break;
    default:
        break;
    }
}

static void finish(bots *b);

static void on_close(session *c, const session_end *end, void *data)
{
    bot *t = data;
    bots *b = t->swarm;
    if (events_conn_end((int)t->idx, end, session_ctx_peer(b->ctx)))
        b->k.errors++;
    if (end->was_open && !end->after_bye && end->kind != SESSION_END_LOCAL) {
        b->k.disconnects++;
        events_closed((int)t->idx);
    }
    session_free(c);
    t->c = NULL;
    b->open--;
    if (b->ending && b->open == 0)
        finish(b);
}

static const session_handler handler = {.on_msg = on_msg, .on_close = on_close};

static void start_bot(bots *b, bot *t)
{
    b->open++;
    if (b->o.no_handshake) {
        t->w.pos[0] = (float)((2 * rand_unit(b) - 1) * BOTS_RAW_HALF);
        t->w.pos[2] = (float)((2 * rand_unit(b) - 1) * BOTS_RAW_HALF);
        t->w.angle = 2 * PI * rand_unit(b);
        t->w.turn_at = ev_now(b->loop) + BOTS_TURN_NS;
        t->c = session_open(b->ctx, NULL, NULL, &handler, t);
        return;
    }
    char name[PROTO_NAME_MAX + 1];
    snprintf(name, sizeof name, "%s-%u", b->o.net.name, t->idx);
    t->c = session_open(b->ctx, name, b->o.net.box, &handler, t);
}

/* ---- timers ------------------------------------------------------------ */

/* Over a WebSocket: forgets the bots whose upgrade is over (answered,
 * refused or never begun); returns 1 if another may start. */
static int upgrade_room(bots *b)
{
    if (!b->o.net.ws)
        return 1;
    unsigned k = 0;
    for (unsigned i = 0; i < b->nupgrading; i++) {
        session *c = b->bot[b->upgrading[i]].c;
        if (c && (session_state(c) == SESSION_CONNECTING || session_state(c) == SESSION_UPGRADING))
            b->upgrading[k++] = b->upgrading[i];
    }
    b->nupgrading = k;
    return k < BOTS_UPGRADES_MAX;
}

/* Starts what the ramp allows by now (over a WebSocket, no more than
 * BOTS_UPGRADES_MAX upgrades at once), then sends every move whose slot
 * has come. A loop that fell more than a period behind skips the missed
 * periods rather than sending them in a burst. */
static void on_tick(ev_loop *loop, void *data)
{
    bots *b = data;
    uint64_t now = ev_now(loop);
    double due = (double)(now - b->t0) / (double)NS_PER_S * b->o.ramp + 1.0;
    unsigned target = due >= (double)b->o.count ? b->o.count : (unsigned)due;
    while (b->started < target && upgrade_room(b)) {
        bot *t = &b->bot[b->started++];
        if (b->o.net.ws)
            b->upgrading[b->nupgrading++] = t->idx;
        start_bot(b, t);
    }
    for (unsigned budget = b->o.count; budget > 0; budget--) {
        uint64_t slot = b->cycle_at + (uint64_t)b->cursor * b->period_ns / b->o.count;
        if (slot > now)
            break;
        serve(b, &b->bot[b->cursor], now);
        if (++b->cursor == b->o.count) {
            b->cursor = 0;
            b->cycle_at += b->period_ns;
            if (now > b->cycle_at && now - b->cycle_at >= b->period_ns)
                b->cycle_at += (now - b->cycle_at) / b->period_ns * b->period_ns;
        }
    }
}

static void fill_counts(bots *b)
{
    b->k.connected = session_ctx_opened(b->ctx);
    b->k.frames_in = session_ctx_frames_in(b->ctx);
    b->k.bytes_in = session_ctx_bytes_in(b->ctx);
}

static double elapsed_s(const bots *b) { return (double)(ev_now(b->loop) - b->t0) / (double)NS_PER_S; }

static void on_stats(ev_loop *loop, void *data)
{
    bots *b = data;
    (void)loop;
    fill_counts(b);
    events_stats(&b->k, elapsed_s(b));
    /* Moves keep bots alive at any usual rate; this covers very slow ones. */
    for (unsigned i = 0; i < b->started; i++)
        if (b->bot[i].c)
            session_keepalive(b->bot[i].c);
}

static void finish(bots *b)
{
    if (b->finished)
        return;
    b->finished = 1;
    session_timer_stop(b->loop, &b->tick_timer);
    session_timer_stop(b->loop, &b->stats_timer);
    session_timer_stop(b->loop, &b->end_timer);
    session_timer_stop(b->loop, &b->linger_timer);
    fill_counts(b);
    events_summary(&b->k, elapsed_s(b));
    ev_stop(b->loop);
}

static void on_linger(ev_loop *loop, void *data)
{
    bots *b = data;
    (void)loop;
    b->linger_timer = -1;
    finish(b);
}

/* Every bot says bye (raw ones just close: they speak only moves); the
 * summary follows when all are closed or after BOTS_LINGER_NS. */
static void begin_end(bots *b)
{
    if (b->ending)
        return;
    b->ending = 1;
    session_timer_stop(b->loop, &b->tick_timer);
    for (unsigned i = 0; i < b->started; i++) {
        session *c = b->bot[i].c;
        if (!c)
            continue;
        if (b->o.no_handshake)
            session_close(c);
        else
            session_bye(c, PROTO_BYE_QUIT);
    }
    if (b->open == 0)
        finish(b);
    else
        b->linger_timer = session_timer_start(b->loop, BOTS_LINGER_NS, 0, on_linger, b);
}

static void on_duration(ev_loop *loop, void *data)
{
    bots *b = data;
    (void)loop;
    b->end_timer = -1;
    begin_end(b);
}

/* ---- public ------------------------------------------------------------ */

bots *bots_create(ev_loop *loop, const bots_opts *o, int *exit_code)
{
    char err[512];
    session_ctx *ctx = session_ctx_create(loop, &o->net, err, sizeof err);
    if (!ctx) {
        fprintf(stderr, "cvre-client: %s\n", err);
        *exit_code = 1;
        return NULL;
    }
    bots *b = cvre_xcalloc(1, sizeof *b);
    b->loop = loop;
    b->ctx = ctx;
    b->o = *o;
    b->bot = cvre_xcalloc(o->count, sizeof *b->bot);
    for (unsigned i = 0; i < o->count; i++) {
        b->bot[i].swarm = b;
        b->bot[i].idx = i;
    }
    b->rng = ((uint64_t)time(NULL) << 20 ^ (uint64_t)getpid()) | 1u;
    b->period_ns = (uint64_t)((double)NS_PER_S / o->rate);
    b->t0 = b->cycle_at = ev_clock(loop);
    b->tick_timer = session_timer_start(b->loop, 0, BOTS_TICK_NS, on_tick, b);
    b->stats_timer = session_timer_start(b->loop, BOTS_STATS_NS, BOTS_STATS_NS, on_stats, b);
    b->end_timer = session_timer_start(b->loop, (uint64_t)(o->duration * (double)NS_PER_S), 0, on_duration, b);
    b->linger_timer = -1;
    return b;
}

void bots_interrupt(bots *b)
{
    if (b->ending)
        finish(b);
    else
        begin_end(b);
}

int bots_exit_code(const bots *b) { return b->k.errors == 0 && b->k.disconnects == 0 ? 0 : 1; }

void bots_free(bots *b)
{
    if (!b)
        return;
    session_timer_stop(b->loop, &b->tick_timer);
    session_timer_stop(b->loop, &b->stats_timer);
    session_timer_stop(b->loop, &b->end_timer);
    session_timer_stop(b->loop, &b->linger_timer);
    for (unsigned i = 0; i < b->o.count; i++)
        session_free(b->bot[i].c);
    session_ctx_free(b->ctx);
    free(b->bot);
    free(b);
}
