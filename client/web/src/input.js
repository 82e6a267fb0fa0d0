/*
 * input.js: walking and looking, and the moves they make.
 *
 * The keyboard (WASD or the arrow keys, Shift to go faster) moves the
 * avatar on the ground relative to where it faces; the mouse turns it,
 * with the pointer locked after a click, or by dragging without the lock.
 *
 * The page predicts: it moves its own avatar at once and sends where it
 * wants to be in MOVE frames, at most once a server tick and only while
 * something changed. The server's answer is authoritative: each SNAPSHOT
 * carries ack_seq, the last move applied, and our own position when it
 * changed. The prediction is then moved by the difference between that
 * position and where we had asked to be at ack_seq, and the moves not yet
 * applied move with it, so a wall or the speed limit corrects the
 * prediction within a round trip while unanswered steps are kept. The
 * prediction itself stops at the objects' collision boxes. Height is the
 * server's alone (it applies gravity and steps; MOVE's y is only
 * carried).
 */
import * as proto from './proto.js';

/* Turning per pixel of mouse movement, radians. */
const INPUT_TURN_PER_PIXEL = 0.0025;
/* Pitch stops short of straight up and down, where yaw would flip. */
const INPUT_PITCH_LIMIT = 1.55;
/* Walking speed, m/s, and the share of the server's limit that running
 * uses: a little under it, so that timer jitter does not make the server
 * cut our steps. */
const INPUT_WALK_SPEED = 2.5;
const INPUT_SPEED_SHARE = 0.9;
/* A position that moved less than this (metres) did not change. */
const INPUT_EPSILON = 1e-4;

const KEYS = {
    KeyW: [0, 1], ArrowUp: [0, 1], KeyS: [0, -1], ArrowDown: [0, -1],
    KeyA: [-1, 0], ArrowLeft: [-1, 0], KeyD: [1, 0], ArrowRight: [1, 0],
};

/*
 * Listens to the keyboard and the mouse on canvas. Returns the input
 * state: yaw (radians about +y; 0 looks along -z) and pitch (up
 * positive), and the keys held.
 */
export function input_new(canvas) {
    const inp = { yaw: 0, pitch: 0, keys: new Set(), run: false, dragging: false };
    /* Keys typed into a text field are the field's; a focused checkbox
     * or button does not take letters, so the walk keeps them. */
    const typing = (e) => (e.target instanceof HTMLInputElement && !['checkbox', 'radio', 'button', 'submit'].includes(e.target.type)) ||
        e.target instanceof HTMLTextAreaElement;
    window.addEventListener('keydown', (e) => {
        if (typing(e))
            return;
        if (KEYS[e.code]) {
            inp.keys.add(e.code);
            e.preventDefault();
        }
        inp.run = e.shiftKey;
    });
    window.addEventListener('keyup', (e) => {
        inp.keys.delete(e.code);
        inp.run = e.shiftKey;
    });
    window.addEventListener('blur', () => inp.keys.clear());
    const turn = (dx, dy) => {
        inp.yaw -= dx * INPUT_TURN_PER_PIXEL;
        inp.pitch = Math.max(-INPUT_PITCH_LIMIT, Math.min(INPUT_PITCH_LIMIT, inp.pitch - dy * INPUT_TURN_PER_PIXEL));
    };
    canvas.addEventListener('mousedown', (e) => {
        if (e.button !== 0)
            return;
        inp.dragging = true;
        /* The lock may be refused (no user gesture, a headless browser):
         * dragging works without it. */
        if (document.pointerLockElement !== canvas && canvas.requestPointerLock) {
            const p = canvas.requestPointerLock();
            if (p && p.catch)
                p.catch(() => {});
        }
    });
    window.addEventListener('mouseup', () => {
        inp.dragging = false;
    });
    window.addEventListener('mousemove', (e) => {
        if (document.pointerLockElement === canvas || inp.dragging)
            turn(e.movementX, e.movementY);
    });
    return inp;
}

/* A new prediction for an avatar that spawned at spawn. */
export function control_new(spawn) {
    return {
        pred: spawn.slice(),  /* where we draw ourselves */
        acked: [spawn[0], spawn[2]], /* what we asked for at the last ack, corrected */
        ack_seq: 0,
        pending: [],          /* {seq, x, z}: moves sent, not yet applied */
        seq: 0,
        sent: null,           /* {x, y, z, key}: the last move sent */
        push: [0, 0, 0],      /* the walk a box kept back since that move */
        next_send: 0,
    };
}

/*
 * Advances the prediction by dt seconds of the keys held, at walking
 * speed (Shift: near the server's max_speed), relative to yaw. A
 * VR thumbstick's [right, forward] may be given as stick. blocked(from,
 * to) tells whether the avatar may not go from one point to the other
 * (world_blocked); each axis is tried on its own, so the prediction
 * slides along a wall as the server's move does instead of walking into
 * it and being pulled back. What a wall kept back is still asked for
 * (control_move): the server must see the user push into the box, since
 * its collisions are what refine the collision maps.
 */
export function control_step(c, inp, dt, max_speed, stick, blocked) {
    let right = 0, fwd = 0;
    for (const k of inp.keys) {
        right += KEYS[k][0];
        fwd += KEYS[k][1];
    }
    if (stick) {
        right += stick[0];
        fwd += stick[1];
    }
    const len = Math.hypot(right, fwd);
    if (len === 0)
        return;
    const top = max_speed * INPUT_SPEED_SHARE;
    const speed = (inp.run ? top : Math.min(INPUT_WALK_SPEED, top)) * Math.min(1, len) / len;
    const s = Math.sin(inp.yaw), co = Math.cos(inp.yaw);
    /* Forward is (-sin yaw, 0, -cos yaw); right is (cos yaw, 0, -sin yaw). */
    const d = [(fwd * -s + right * co) * speed * dt, 0, (fwd * -co + right * -s) * speed * dt];
    for (const k of [0, 2]) {
        const to = c.pred.slice();
        to[k] += d[k];
        if (!blocked(c.pred, to))
            c.pred = to;
        else
            c.push[k] += d[k];
    }
}

/*
 * Takes the server's answer (SNAPSHOT): ack_seq and our own position if
 * the snapshot had it. Moves the prediction and the unapplied moves by
 * the difference between the server's position and what we had asked
 * for at ack_seq; takes the height as it is.
 */
export function control_correct(c, ack_seq, auth_pos, last_auth) {
    if (ack_seq > c.ack_seq) {
        while (c.pending.length && c.pending[0].seq <= ack_seq) {
            const p = c.pending.shift();
            if (p.seq === ack_seq)
                c.acked = [p.x, p.z];
        }
        c.ack_seq = ack_seq;
    } else if (!auth_pos) {
        return;
    }
    const pos = auth_pos || last_auth;
    const dx = pos[0] - c.acked[0], dz = pos[2] - c.acked[1];
    c.pred[0] += dx;
    c.pred[2] += dz;
    c.pred[1] = pos[1];
    for (const p of c.pending) {
        p.x += dx;
        p.z += dz;
    }
    c.acked = [pos[0], pos[2]];
}

/*
 * The MOVE to send now, or null: none before next_send (one a server
 * tick), none when neither the position nor the pose changed and no box
 * kept the walk back. pose is a quantized pose (proto.proto_pose_fit).
 * The move asks for the predicted position plus what a box kept back
 * (into the box: the server stops the avatar and reports the collision);
 * the prediction is what is kept for the correction, since that is where
 * the avatar is expected to end.
 */
export function control_move(c, now, tick_ms, pose) {
    if (now < c.next_send)
        return null;
    const key = JSON.stringify(pose);
    const s = c.sent, pushing = c.push[0] !== 0 || c.push[2] !== 0;
    if (s && !pushing && Math.abs(s.x - c.pred[0]) < INPUT_EPSILON && Math.abs(s.z - c.pred[2]) < INPUT_EPSILON && s.key === key)
        return null;
    c.seq++;
    c.sent = { x: c.pred[0], z: c.pred[2], key };
    c.pending.push({ seq: c.seq, x: c.pred[0], z: c.pred[2] });
    c.next_send = now + tick_ms;
    const want = [c.pred[0] + c.push[0], c.pred[1], c.pred[2] + c.push[2]];
    c.push = [0, 0, 0];
    return proto.proto_put_move(c.seq, want, pose);
}
