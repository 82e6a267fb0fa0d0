/*
 * judge.h: whether a refined collision map is better than the one in force,
 * found by walking the avatar controller (algo/scene/move.h) through both
 * maps from the collisions that asked for the refinement. A map is never
 * published unless it is better (server/pipeline/apply.c). Pure module: no
 * I/O, no global state; the index of the triangles may be built on a second
 * thread (threads below); the same input always gives the same output
 * (times aside).
 *
 * Everything is simulated in the object's metric frame: local coordinates
 * times the object's scale (so that the avatar's size, gravity and step
 * height are in metres), y up; the world's floor y = 0 is the plane
 * y = -pose_y there, pose_y being the height of the object's origin. Other
 * objects are not part of the trial.
 *
 * The trial. Each sample is a logged collision: where the avatar's feet were
 * and how it moved (equal samples, a user pressing on a box tick after
 * tick, count once; past max_samples, an even choice). From each, in each
 * of three directions (the sample's
 * horizontal direction, and that turned by +-deflect, so that the trial also
 * tries the space beside the line the user took), the avatar walks at the
 * sample's horizontal speed (or `speed` when it is nearly still) for as many
 * ticks of dt as cover `reach` metres, once against the old boxes and once
 * against the new, with gravity and steps up as on the server: an opening
 * that leads onto a step and on under a box is tried as a user would.
 * Against the new map, a sample that a new box encloses and no old box did
 * starts where the server puts such an avatar when the map comes in force:
 * pushed out of the new boxes (move.h, move_push_out). Per
 * map, every tick counts as
 *
 *   - a phantom block when a box of the map held the avatar back (an inside
 *     contact, or a blocking one that left it less than JUDGE_HELD_BACK of
 *     its horizontal motion: sliding along a wall met at a glance is not
 *     being stopped) while its box, grown by one cell of the refinement's
 *     grid over the object's bounding box (cell_depth) sideways and
 *     upwards, its bottom raised by
 *     JUDGE_FLOOR_TOLERANCE (what it stands on is support), touches no
 *     triangle: the map stopped a user where nothing real was
 *     (tests/bench/scenario.py's phantom check), for JUDGE_HELD_TICKS
 *     ticks in a row or more (each of them counts, and so does a run the
 *     trial's last tick cuts short; a lone tick is a corner met at a
 *     glance: trials deflected by 30 degrees graze a garage's bounding box
 *     at its corners, users do not stop there);
 *   - opened when the avatar's box, shrunk by JUDGE_LEAK_TOLERANCE, ends the
 *     tick overlapping a triangle: the map let a user into real geometry.
 *
 * Verdict: the new map is better iff it removes at least
 * JUDGE_GAIN_NUM / JUDGE_GAIN_DEN of the old one's phantom blocks (and at
 * least JUDGE_GAIN_MIN) and opens no more than the old one (none where the
 * old one opened nothing).
 *
 * "Touches a triangle" is answered by an occupancy grid of 2^depth cells per
 * axis (voxel.h, conservative: a cell a triangle may touch is occupied)
 * with a summed-volume table, so a box far from the geometry costs O(1); a
 * "maybe" is then confirmed with the exact triangle-box test on the
 * triangles binned near the avatar. Both tests need the exact one: the
 * centimetre by which the avatar's box is raised from what it stands on is
 * less than a cell. The grid and the bins hold only the triangles whose
 * bounding box meets the region the trials can reach sideways (the samples'
 * walks, grown by half the avatar and a cell; any height): a move takes
 * the avatar no further sideways than it asks (move.h). A box outside that
 * region would be tested against every triangle, so the figures never
 * depend on it.
 *
 * Costs: a pass over the triangles for their bounds and one for those near
 * the samples; building the grid is one pass over those (voxel_mark) plus
 * 4 (2^depth + 1)^3 bytes for the table (144 KiB at depth 5; 2^(3 depth)
 * more while it is built), sorting the
 * samples is O(n log n); the bins hold
 * each triangle at most JUDGE_BIN_SPREAD_MAX times. Then at most
 * max_samples x 3 directions x 2 maps x JUDGE_TICKS_MAX ticks, each one
 * move_step against the boxes near the avatar plus O(1) grid tests (the
 * exact test only near triangles). A run stuck in place (the same state
 * after a tick as before) is not simulated further: every later tick would
 * be the same, and is counted as such.
 */
#ifndef CVRE_ECM_JUDGE_H
#define CVRE_ECM_JUDGE_H

#include <stddef.h>
#include <stdint.h>

#include "move.h"
#include "trimesh.h"

/* The server's tick at its default 20 Hz (server/srv_limits.h). */
#define JUDGE_DT_DEFAULT 0.05f
/* How far each trial walks: past a doorway and a room's first metres, far
 * enough to reach what an opening leads to (a step, a low roof). */
#define JUDGE_REACH_DEFAULT 3.0f
/* Walking pace for samples logged nearly still (below JUDGE_SPEED_MIN). */
#define JUDGE_SPEED_DEFAULT 1.5f
#define JUDGE_SPEED_MIN 0.3f
/* The deflected directions: +-30 degrees. */
#define JUDGE_DEFLECT_DEFAULT 0.5235988f
/* Distinct samples judged at most: chosen evenly from those given. Clusters
 * are a few places users were stopped at, so a hundred-odd samples cover
 * them; 128 x 3 directions x 2 maps x about 40 ticks are some 30,000
 * moves, about 30 ms. */
#define JUDGE_SAMPLES_DEFAULT 128u
#define JUDGE_SAMPLES_LIMIT 65536u
/* Ticks a trial takes at most (reach at JUDGE_SPEED_MIN and the shortest
 * tick would be more; the speed is raised to fit). */
#define JUDGE_TICKS_MAX 400u
/* A move held back: the avatar made less than half the horizontal motion
 * it asked for. A user walking 30 degrees off a wall slides on at 87% of
 * its speed; one walking into it, or 60 degrees off it, is stopped or
 * halved. Without it, the deflected trials charged a map that opens a
 * doorway for the walls of the corridor behind it, while the old map
 * stopped the same users at once and then held them on the door's real
 * jamb, which is no phantom. */
#define JUDGE_HELD_BACK 0.5
/* Phantom blocks count in runs of at least this many ticks (see above):
 * at a garage's bounding box the old map's 10 blocks and the candidate's
 * 6 were all lone ticks of different trials, and the candidate, published
 * on that, stopped a user the single box never had. */
#define JUDGE_HELD_TICKS 2u

/* The least share of the old map's phantom blocks a new map must remove,
 * as a fraction JUDGE_GAIN_NUM / JUDGE_GAIN_DEN: a few blocks fewer on a
 * hundred-odd samples is within the trials' noise, no evidence that users
 * are stopped less (the scenario's desk published maps judged 864 -> 861
 * and 29 -> 25; users met as many phantoms with them as without). */
#define JUDGE_GAIN_NUM 1u
#define JUDGE_GAIN_DEN 4u
/* And at least this many blocks: one trial held back for a tick or two at
 * a corner is how the trials fall, not a place users are stopped at (a
 * user stopped there is held back tick after tick). */
#define JUDGE_GAIN_MIN 4u

/* How far the avatar's box may reach down into what it stands on and still
 * not touch it (phantom test), and how far into a triangle it must be to
 * count as let in (opened test): a centimetre, as the scenario checks. */
#define JUDGE_FLOOR_TOLERANCE 0.01f
#define JUDGE_LEAK_TOLERANCE 0.01f
/* The occupancy grid: 2^5 cells a side (144 KiB of table). It only spares
 * the exact test the boxes far from the geometry; near it (an avatar on a
 * tread) every grid says "maybe", so a finer one bought little for what
 * marking it cost: the judge's ms summed over job 1 of the scenario's
 * seven scenes and job 3 of its archway and staircase (cvre-cluster
 * --json on copies of the runner's databases) were 102-111 at 2^6 with
 * 32^3 bins, 60-76 at 2^5 with 16^3 and 146-149 at 2^7; bench-refine's
 * bunny 9.2 -> 5.1 ms. Its verdicts are the exact test's at any depth. */
#define JUDGE_DEPTH_DEFAULT 5u

/* A triangle whose bounding box spans more bins than this is kept on a
 * list every exact test looks at, so that the bins stay within this many
 * entries a triangle. */
#define JUDGE_BIN_SPREAD_MAX 64u

typedef struct judge_params {
    move_params move;      /* avatar size, gravity, step height, m; floor_y is set from pose_y */
    float dt;              /* tick, s, in (0, MOVE_MAX_DT] */
    float reach;           /* m a trial walks, in (0, 100] */
    float speed;           /* m/s for samples nearly still, in [JUDGE_SPEED_MIN, 100] */
    float deflect;         /* radians, [0, pi/2]; 0: only the sample's own direction */
    uint32_t depth;        /* the occupancy grid's depth, VOXEL_DEPTH_MIN..8 */
    uint32_t cell_depth;   /* the grid whose cell is the phantom tolerance, VOXEL_DEPTH_MIN..VOXEL_DEPTH_MAX */
    uint32_t max_samples;  /* 1..JUDGE_SAMPLES_LIMIT */
    unsigned threads;      /* 1: this thread alone; else the triangles' index is built on a second
                            * (0: when the machine has more than one CPU) */
} judge_params;

/* Fills p with the defaults above, the default avatar (move.h), an
 * occupancy grid of JUDGE_DEPTH_DEFAULT and the refinement's grid depth for
 * the tolerance (refine.h: its cells). */
void judge_params_default(judge_params *p);

/* A logged collision in the object's metric frame. */
typedef struct judge_sample {
    float pos[3]; /* the avatar's feet */
    float vel[3]; /* its velocity, m/s */
} judge_sample;

typedef struct judge_input {
    const trimesh *mesh;          /* the object's triangles, local */
    double scale;                 /* metres per local unit, > 0 */
    double pose_y;                /* world height of the object's origin, m */
    const float (*old_boxes)[6];  /* the map in force, local */
    uint32_t nold;
    const float (*new_boxes)[6];  /* the candidate, local */
    uint32_t nnew;
    const judge_sample *samples;
    uint32_t nsamples;
} judge_input;

typedef struct judge_result {
    int better;           /* 1: publish the candidate */
    uint32_t samples;     /* judged: distinct ones (equal samples count once), at most max_samples */
    uint32_t still;       /* of which without a horizontal direction: not walked */
    uint64_t moves;       /* ticks per map */
    uint64_t phantom_old, phantom_new;
    uint64_t opened_old, opened_new;
    double ms;            /* CPU time: the calling thread's (CLOCK_THREAD_CPUTIME_ID) and a task's */
} judge_result;

/* The verdict on r's figures (see above): 1 when the new map is better. */
int judge_better(const judge_result *r);
/* Whether after phantom blocks remove at least num / den of before's, and
 * at least JUDGE_GAIN_MIN (judge_better's gain; algo/refine/second.c asks
 * a second candidate for more). */
int judge_gain(uint64_t before, uint64_t after, uint32_t num, uint32_t den);

/*
 * Judges in->new_boxes against in->old_boxes (see above) and fills *out,
 * whatever the verdict: judge_open, judge_new and judge_close in one.
 * Returns 0, or with *out zeroed and a one-line reason in err (room for
 * errlen bytes): -EINVAL for parameters out of range, no mesh, no boxes or
 * more than ECM_MAX_BOXES_LIMIT, a box's coordinate, the scale or pose_y
 * not finite (or a scale not above 0), a box with min > max, no samples,
 * or a sample with a coordinate that is not finite or beyond
 * MOVE_MAX_COORD; -ENOMEM when out of memory.
 */
int judge_maps(const judge_params *p, const judge_input *in, judge_result *out, char *err, size_t errlen);

/*
 * The same in steps, so that the old map can be walked before there is a
 * new one (server/pipeline/apply.c: a map that no candidate could beat is
 * not refined at all). judge_open checks everything but the new map
 * (in->new_boxes is not read), indexes the geometry, walks the old map and
 * fills *old with its figures (samples, still, moves, phantom_old,
 * opened_old, ms; the rest 0); in and what it points to must outlive *j.
 * judge_new walks a new map and fills *out as judge_maps does (ms: the
 * old map's walks and these); it may be called again with another map.
 * Errors as judge_maps's (*j NULL after a failed open; judge_close(NULL)
 * does nothing).
 */
typedef struct judge judge;
int judge_open(judge **j, const judge_params *p, const judge_input *in, judge_result *old, char *err,
               size_t errlen);
int judge_new(judge *j, const float (*boxes)[6], uint32_t n, judge_result *out, char *err, size_t errlen);
void judge_close(judge *j);

/* Where the trials of the last map judge_new walked met its phantom blocks:
 * at each place, the avatar's box (local: feet to head, as refine.h's
 * ecm_stood), the point where it met the box that held it back (local), that
 * box's index in the map and the phantom ticks counted there (a stuck
 * avatar's ticks at one place). Their ticks sum to phantom_new, but for a
 * place out of memory left out: they guide a second candidate
 * (algo/refine/second.c), they are no figure. Valid until the next
 * judge_new or judge_close; none before a judge_new. */
typedef struct judge_place {
    float box[6];
    float point[3];
    uint32_t hit;
    uint32_t ticks;
} judge_place;
void judge_places(const judge *j, const judge_place **places, uint32_t *n);

/* Whether any new map could be better than the old one with these
 * figures (judge_open's): the verdict asks for at least JUDGE_GAIN_MIN
 * phantom blocks fewer, so an old map with fewer on the trials wins
 * against every candidate. */
int judge_can_gain(const judge_result *old);

#endif
