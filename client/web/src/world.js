/*
 * world.js: what the page knows of the world, from the server's frames:
 * its own avatar, the other avatars in view with their poses, the objects
 * it was told of, their meshes (downloaded once per hash and kept for the
 * page's life) and the recent collisions. No three.js here: view.js draws
 * from this state, input.js predicts from it.
 *
 * Meshes are asked for a few at a time (MESH_REQUEST) and within the
 * server's rate, nearest objects first since the server announces them
 * nearest first; the chunks of one
 * mesh come in order and whole before the next (PROTOCOL.md, section 5,
 * "Meshes") and are put together, checked and decoded here.
 */
import * as proto from './proto.js';

const { T, S } = proto;

/* Mesh requests waiting at the server at once: under its 16 waiting. */
const WORLD_MESH_IN_FLIGHT = 8;
/* The server's rate for mesh requests (PROTOCOL.md, section 5, "Meshes":
 * a burst of 32, then 8 a second, per address), kept here too so that a
 * page alone on its address is not refused: a little under it, since the
 * server's clock is its tick's and the requests arrive a moment after
 * they leave. */
const WORLD_MESH_BURST = 30;
const WORLD_MESH_PER_S = 7;
/* After a RATE_LIMITED refusal (other pages share the address), ask
 * again this much later. */
const WORLD_MESH_RETRY_MS = 1000;
/* Collisions kept for the markers: the last few seconds' worth. */
const WORLD_COLLISIONS_KEEP = 64;
export const WORLD_COLLISION_SHOW_MS = 3000;

/*
 * A new, empty world. send(frame) sends a frame on the session (false when
 * it could not); hooks are called as things happen:
 *   on_own(ack_seq, pos | null): each SNAPSHOT, with our own entry if any;
 *   on_upload_object(info): OBJECT_INFO answering our upload (upload_id);
 *   on_upload_rejected(m): OBJECT_REJECTED that is not a mesh request's;
 *   on_problem(words): something went wrong that the user should read.
 */
export function world_new(send, hooks) {
    return {
        send,
        hooks,
        welcome: null,
        self: null,            /* {id, name, pos, box} */
        avatars: new Map(),    /* id -> {id, name, pos, box, pose (decoded) | null} */
        objects: new Map(),    /* id -> OBJECT_INFO fields, and mesh_refused */
        meshes: new Map(),     /* hash -> decoded mesh (proto_mesh_decode) */
        mesh_failed: new Set(), /* hashes whose mesh did not decode: not asked again */
        mesh_in_flight: new Map(), /* object id -> {hash, tri_count} asked for */
        mesh_rx: null,         /* the mesh being received: {object_id, total, parts, len} */
        mesh_hold_until: 0,
        mesh_tokens: WORLD_MESH_BURST, /* requests the rate allows now */
        mesh_tokens_at: performance.now(),
        mesh_timer: 0,
        collisions: [],        /* {point, normal, object_id, t} */
        collision_count: 0,
    };
}

export function world_welcome(w, welcome) {
    w.welcome = welcome;
}

export function world_joined(w, name, join_ok) {
    w.self = { id: join_ok.avatar_id, name, pos: join_ok.pos.slice(), box: join_ok.box.slice() };
}

/* Handles one frame of a joined session (session.js on_frame). */
export function world_frame(w, type, m) {
    switch (type) {
    case T.SNAPSHOT: {
        let own = null;
        for (const e of m.entries) {
            if (e.id === w.self.id)
                own = e.pos;
            else if (w.avatars.has(e.id))
                w.avatars.get(e.id).pos = e.pos;
            /* An entry for an id we were not told of is ignored (section 4). */
        }
        if (own)
            w.self.pos = own;
        w.hooks.on_own(m.ack_seq, own);
        break;
    }
    case T.AVATAR_JOINED:
        w.avatars.set(m.id, { id: m.id, name: m.name, pos: m.pos, box: m.box, pose: null });
        break;
    case T.AVATAR_LEFT:
        w.avatars.delete(m.id);
        break;
    case T.AVATAR_POSE:
        if (w.avatars.has(m.id))
            w.avatars.get(m.id).pose = m.pose;
        break;
    case T.OBJECT_INFO: {
        /* Keep the highest collision-map version (section 5); a move
         * resends the same version with the new transform. */
        const old = w.objects.get(m.object_id);
        if (old && m.ecm_version < old.ecm_version)
            break;
        m.mesh_refused = old && old.mesh_hash === m.mesh_hash ? old.mesh_refused : false;
        w.objects.set(m.object_id, m);
        if (m.upload_id !== 0)
            w.hooks.on_upload_object(m);
        mesh_pump(w);
        break;
    }
    case T.OBJECT_REMOVED:
        w.objects.delete(m.object_id);
        break;
    case T.OBJECT_REJECTED:
        if (!mesh_rejected(w, m))
            w.hooks.on_upload_rejected(m);
        break;
    case T.MESH_CHUNK:
        mesh_chunk(w, m);
        break;
    case T.COLLISION:
        w.collision_count++;
        w.collisions.push({ point: m.point, normal: m.normal, object_id: m.object_id, t: performance.now() });
        if (w.collisions.length > WORLD_COLLISIONS_KEEP)
            w.collisions.shift();
        break;
    default:
        break;
    }
}

/* Drops the collisions older than WORLD_COLLISION_SHOW_MS. */
export function world_prune(w, now) {
    while (w.collisions.length && now - w.collisions[0].t > WORLD_COLLISION_SHOW_MS)
        w.collisions.shift();
}

/* ---- moving ------------------------------------------------------------ */

/* A box whose top is at most this far above the feet is a step the server
 * climbs (protocol/avatar.h, AVATAR_STEP), not a wall. */
const WORLD_STEP = 0.35;

/* Whether an avatar of size s with its feet at p overlaps box b, not
 * counting a box it can step onto. */
function overlaps(b, p, s) {
    return b.max[1] > p[1] + WORLD_STEP && b.min[1] < p[1] + s[1] &&
        b.min[0] < p[0] + s[0] / 2 && b.max[0] > p[0] - s[0] / 2 &&
        b.min[2] < p[2] + s[2] / 2 && b.max[2] > p[2] - s[2] / 2;
}

/*
 * Whether our avatar, going from `from` to `to`, would walk into an
 * object's collision box: one it overlaps at `to` and not at `from`
 * (the server ignores the boxes an avatar already stands in, so that it
 * can walk out of them). A guess for the prediction; the server decides.
 */
export function world_blocked(w, from, to) {
    const s = w.self.box;
    for (const o of w.objects.values())
        for (const b of o.boxes)
            if (overlaps(b, to, s) && !overlaps(b, from, s))
                return true;
    return false;
}

/* ---- meshes ------------------------------------------------------------ */

function hash_wanted(w, hash) {
    if (w.meshes.has(hash) || w.mesh_failed.has(hash))
        return false;
    for (const f of w.mesh_in_flight.values())
        if (f.hash === hash)
            return false;
    return true;
}

/* Calls mesh_pump again at time `at` (once, however often asked). */
function mesh_later(w, at) {
    if (!w.mesh_timer)
        w.mesh_timer = setTimeout(() => {
            w.mesh_timer = 0;
            mesh_pump(w);
        }, Math.max(0, at - performance.now()));
}

/* Asks for the meshes the page lacks, in the order the objects came,
 * while fewer than WORLD_MESH_IN_FLIGHT requests wait and the rate
 * allows; each hash once. */
function mesh_pump(w) {
    const now = performance.now();
    if (now < w.mesh_hold_until) {
        mesh_later(w, w.mesh_hold_until);
        return;
    }
    w.mesh_tokens = Math.min(WORLD_MESH_BURST, w.mesh_tokens + (now - w.mesh_tokens_at) * WORLD_MESH_PER_S / 1000);
    w.mesh_tokens_at = now;
    for (const o of w.objects.values()) {
        if (w.mesh_in_flight.size >= WORLD_MESH_IN_FLIGHT)
            return;
        if (o.mesh_refused || w.mesh_in_flight.has(o.object_id) || !hash_wanted(w, o.mesh_hash))
            continue;
        if (w.mesh_tokens < 1) {
            mesh_later(w, now + (1 - w.mesh_tokens) * 1000 / WORLD_MESH_PER_S);
            return;
        }
        if (!w.send(proto.proto_put_mesh_request(o.object_id, o.mesh_hash)))
            return;
        w.mesh_tokens -= 1;
        w.mesh_in_flight.set(o.object_id, { hash: o.mesh_hash, tri_count: o.tri_count });
    }
}

/* Ends the fetch of object_id's mesh (done or failed) and asks for more. */
function mesh_done(w, object_id) {
    w.mesh_in_flight.delete(object_id);
    if (w.mesh_rx && w.mesh_rx.object_id === object_id)
        w.mesh_rx = null;
    mesh_pump(w);
}

/* Takes an OBJECT_REJECTED that answers one of our mesh requests;
 * returns false for anything else (an upload's). The codes tell them
 * apart where the ids could meet (an upload id is ours to pick, an object
 * id the server's). */
function mesh_rejected(w, m) {
    const mesh_code = m.code === S.NO_OBJECT || m.code === S.STALE_MESH || m.code === S.RATE_LIMITED;
    if (!w.mesh_in_flight.has(m.request_id) || !(mesh_code || m.code === S.INTERNAL))
        return false;
    const o = w.objects.get(m.request_id);
    if (m.code === S.RATE_LIMITED) {
        w.mesh_hold_until = performance.now() + WORLD_MESH_RETRY_MS;
    } else if (o) {
        /* NO_OBJECT: it left our view meanwhile (an OBJECT_REMOVED
         * follows); the others are not asked again for this object. */
        o.mesh_refused = true;
        if (m.code !== S.NO_OBJECT)
            w.hooks.on_problem(`the mesh of object ${m.request_id} (${o.name}) was refused: ` +
                `${proto.proto_strerror(m.code)}${m.message ? ': ' + m.message : ''}`);
    }
    mesh_done(w, m.request_id);
    return true;
}

function mesh_fail(w, object_id, words) {
    const f = w.mesh_in_flight.get(object_id);
    if (f)
        w.mesh_failed.add(f.hash);
    w.hooks.on_problem(`the mesh of object ${object_id} could not be shown: ${words}`);
    mesh_done(w, object_id);
}

/*
 * Puts a mesh together from its chunks: in order (offset = bytes so far),
 * one total, for an object we asked for, and no larger than its triangle
 * count allows (32 + 30 bytes a triangle); the buffer grows with the
 * chunks. The whole is then decoded with the C decoder's checks. A mesh
 * that breaks a rule is not shown and not asked for again; the session
 * goes on, as the reference client's fetch fails and keeps it.
 */
function mesh_chunk(w, m) {
    let rx = w.mesh_rx;
    if (m.offset === 0) {
        const f = w.mesh_in_flight.get(m.object_id);
        if (!f) {
            w.hooks.on_problem(`the server sent a mesh for object ${m.object_id}, which was not asked for`);
            return;
        }
        if (m.total > proto.PROTO_MESH_HEAD_SIZE + 30 * f.tri_count) {
            mesh_fail(w, m.object_id, `${m.total} bytes are too many for ${f.tri_count} triangles`);
            return;
        }
        rx = w.mesh_rx = { object_id: m.object_id, total: m.total, parts: [], len: 0 };
    }
    if (!rx || rx.object_id !== m.object_id || rx.total !== m.total || rx.len !== m.offset) {
        if (w.mesh_in_flight.has(m.object_id))
            mesh_fail(w, m.object_id, 'its chunks came out of order');
        return;
    }
    rx.parts.push(m.data);
    rx.len += m.data.length;
    if (rx.len < rx.total)
        return;
    const bytes = new Uint8Array(rx.total);
    for (let i = 0, at = 0; i < rx.parts.length; at += rx.parts[i].length, i++)
        bytes.set(rx.parts[i], at);
    const f = w.mesh_in_flight.get(m.object_id);
    const d = proto.proto_mesh_decode(bytes);
    if (d.status !== S.OK) {
        mesh_fail(w, m.object_id, `it does not decode (${proto.proto_strerror(d.status)})`);
        return;
    }
    if (d.mesh.tri_count !== f.tri_count) {
        mesh_fail(w, m.object_id, `it has ${d.mesh.tri_count} triangles, not the ${f.tri_count} announced`);
        return;
    }
    w.meshes.set(f.hash, d.mesh);
    mesh_done(w, m.object_id);
}
