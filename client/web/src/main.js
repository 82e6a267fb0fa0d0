/*
 * main.js: the page. Joins (at once with ?name=NAME, else from the form),
 * runs the frame loop (input, prediction, moves, the scene), takes dropped
 * files, and gives tests and the console window.cvre: state() and
 * setXRPose(). The modules: proto.js (the codec), session.js (the
 * WebSocket), world.js (what we know), input.js (walking, prediction),
 * view.js (three.js), xr.js (WebXR), upload.js (drops), ui.js (panels).
 */
import * as proto from './proto.js';
import { session_open, session_send, session_buffered, session_quit } from './session.js';
import { world_new, world_welcome, world_joined, world_frame, world_prune, world_blocked } from './world.js';
import { input_new, control_new, control_step, control_correct, control_move } from './input.js';
import { view_new, view_set_bounds, view_sync, view_sync_objects, view_place_camera, view_render, view_pick,
    view_drawn_triangles, VIEW_EYE_HEIGHT } from './view.js';
import { xr_new, xr_presenting, xr_track, xr_pose, xr_set_override, xr_facing, xr_stick } from './xr.js';
import { upload_new, upload_start, upload_place, upload_object, upload_rejected } from './upload.js';
import { ui_new, ui_form, ui_status, ui_error, ui_users, ui_show_boxes, ui_show_collisions, ui_hud } from './ui.js';

/* The avatar's box, metres: the server's default avatar (protocol/avatar.h). */
const MAIN_AVATAR_BOX = [0.6, 1.8, 0.6];

const page = {
    status: 'form', /* form, connecting, joined, closed */
    session: null,
    world: null,
    control: null,
    upload: null,
    ticker: 0,
};

const canvas = document.getElementById('view');
const view = view_new(canvas);
/* A ground under the form until a server's WELCOME gives the world's. */
view_set_bounds(view, [-512, 0, -512], [512, 0, 512]);
const xr = xr_new(view, document.body);
const input = input_new(canvas);
const ui = ui_new(join);

/* Opens a session and joins as name (a guest when password is empty). */
function join(name, password) {
    const bad = proto.proto_name_problem(name);
    if (bad) {
        ui_error(ui, `cannot join: ${bad}`);
        return;
    }
    if (proto.proto_password_bytes(password) > proto.PROTO_PASSWORD_MAX) {
        ui_error(ui, `cannot join: a password is at most ${proto.PROTO_PASSWORD_MAX} bytes`);
        return;
    }
    if (page.session && page.status !== 'closed')
        return;
    ui_form(ui, false);
    page.status = 'connecting';
    ui_status(ui, `connecting as ${name}${password ? '' : ' (guest)'}…`);
    const send = (frame) => page.session !== null && session_send(page.session, frame);
    page.upload = upload_new({
        send,
        buffered: () => session_buffered(page.session),
        status: (words) => ui_status(ui, words),
        problem: (words) => ui_error(ui, words),
    });
    const world = page.world = world_new(send, {
        on_own: (ack, own) => control_correct(page.control, ack, own, world.self.pos),
        on_upload_object: (info) => upload_object(page.upload, info),
        on_upload_rejected: (m) => upload_rejected(page.upload, m),
        on_problem: (words) => ui_error(ui, words),
    });
    const url = `${location.protocol === 'https:' ? 'wss' : 'ws'}://${location.host}/`;
    page.session = session_open(url, name, password, MAIN_AVATAR_BOX, {
        on_welcome: (w) => {
            world_welcome(world, w);
            view_set_bounds(view, w.world_min, w.world_max);
        },
        on_join_ok: (j) => {
            world_joined(world, name, j);
            page.control = control_new(j.pos);
            page.status = 'joined';
            page.ticker = setInterval(tick, 1000 / world.welcome.tick_hz);
            users();
            ui_status(ui, `joined as ${name}${password ? '' : ' (guest)'}, avatar ${j.avatar_id}`);
        },
        on_frame: (type, m) => {
            world_frame(world, type, m);
            if (type === proto.T.AVATAR_JOINED || type === proto.T.AVATAR_LEFT)
                users();
            wake();
        },
        on_end: (words, is_error) => {
            page.status = 'closed';
            clearInterval(page.ticker);
            users();
            wake();
            if (is_error)
                ui_error(ui, words);
            ui_status(ui, `session ended: ${words}`);
            ui_form(ui, true, name);
        },
    });
}

/* The list of users present, kept by the frames that change it rather
 * than by the animation frames, which a background tab does not get. */
function users() {
    const w = page.world, joined = page.status === 'joined';
    ui_users(ui, joined ? w.self.name : null, joined ? [...w.avatars.values()] : []);
}

/* A frame is drawn while something may change on screen: for this long
 * after the last frame from the server, input or change of the panel's
 * toggles (avatars glide and markers fade meanwhile), and always in VR.
 * An idle page draws nothing, which a software renderer feels. */
const MAIN_RENDER_AFTER_MS = 1000;
/* The longest step of the walk: a page that was not run for a while (a
 * tab in the background) does not jump. */
const MAIN_STEP_MAX_S = 0.25;

let last_step = performance.now();
let render_until = 0;

function wake() {
    render_until = performance.now() + MAIN_RENDER_AFTER_MS;
}

/*
 * Walks and sends: advances the prediction by the time since the last
 * call, with the facing from the tracked head (VR or setXRPose) if there
 * is one, and sends the MOVE if one is due. Called from each animation
 * frame, and from a timer at the server's tick rate so that a page that
 * gets no animation frames (a background tab) still sends its moves.
 */
function tick() {
    const now = performance.now();
    const dt = Math.min(MAIN_STEP_MAX_S, (now - last_step) / 1000);
    last_step = now;
    if (page.status !== 'joined')
        return;
    const w = page.world;
    const parts = xr_pose(xr, view);
    if (parts && parts.head)
        Object.assign(input, xr_facing(parts.head.q));
    control_step(page.control, input, dt, w.welcome.max_speed, xr_stick(view), (a, b) => world_blocked(w, a, b));
    const pose = proto.proto_pose_fit(input.yaw, input.pitch, parts);
    const move = control_move(page.control, now, 1000 / w.welcome.tick_hz, pose);
    if (move) {
        session_send(page.session, move);
        wake();
    }
}

/* One animation frame: the XR poses of this frame, the walk, then the
 * scene, drawn if anything may have changed. */
function frame() {
    const now = performance.now();
    const in_xr = xr_presenting(view);
    if (in_xr)
        xr_track(xr, view);
    tick();
    const w = page.world, joined = page.status === 'joined';
    if (w)
        world_prune(w, now);
    if (!in_xr && now >= render_until)
        return;
    const me = page.control ? page.control.pred : [0, 0, 0];
    const box = w && w.self ? w.self.box : MAIN_AVATAR_BOX;
    view_place_camera(view, me, VIEW_EYE_HEIGHT * box[1], input.yaw, input.pitch, in_xr);
    if (w) {
        view_sync(view, w, {
            show_boxes: ui_show_boxes(), show_collisions: ui_show_collisions(),
            pose_of: proto.proto_pose_metres, dt: frame_dt(now), self_pos: me, now,
        });
        const rtt = page.session && page.session.rtt_ms !== null ? `, round trip ${page.session.rtt_ms.toFixed(0)} ms` : '';
        ui_hud(ui, joined ? `(${me.map((c) => c.toFixed(1)).join(', ')}) · ${w.objects.size} objects, ` +
            `${w.meshes.size} meshes${rtt}` : '');
    }
    view_render(view);
}

let last_frame = performance.now();
function frame_dt(now) {
    const dt = Math.min(MAIN_STEP_MAX_S, (now - last_frame) / 1000);
    last_frame = now;
    return dt;
}

view.renderer.setAnimationLoop(frame);
for (const ev of ['keydown', 'keyup', 'mousemove', 'mousedown', 'wheel', 'resize', 'change'])
    window.addEventListener(ev, wake);

window.addEventListener('dragover', (e) => {
    e.preventDefault();
    e.dataTransfer.dropEffect = 'copy';
});
window.addEventListener('drop', (e) => {
    e.preventDefault();
    const files = e.dataTransfer.files;
    if (!files.length)
        return;
    if (page.status !== 'joined') {
        ui_error(ui, `${files[0].name}: join first, then drop a model to place it`);
        return;
    }
    if (files.length > 1)
        ui_error(ui, `${files.length} files dropped: only ${files[0].name} is uploaded (one at a time)`);
    const at = upload_place(view_pick(view, e.clientX, e.clientY), page.control.pred, input.yaw);
    upload_start(page.upload, files[0], at);
});
window.addEventListener('pagehide', () => {
    if (page.session)
        session_quit(page.session);
});

/* A plain, JSON-able picture of the page for tests and the console
 * (client/web/README.md gives the fields). The scene's objects are first
 * brought in line with the world, as the next frame would, so that a page
 * that gets no animation frames (a background tab) tells what it draws. */
function state() {
    const w = page.world, joined = page.status === 'joined';
    if (w)
        view_sync_objects(view, w, ui_show_boxes());
    const vec = (p) => [p[0], p[1], p[2]];
    return {
        status: page.status,
        self: joined ? { id: w.self.id, name: w.self.name, pos: vec(w.self.pos) } : null,
        avatars: w ? [...w.avatars.values()].map((a) => ({
            id: a.id, name: a.name, pos: vec(a.pos), pose: a.pose ? proto.proto_pose_metres(a.pose) : null,
        })) : [],
        objects: w ? [...w.objects.values()].map((o) => ({
            id: o.object_id, name: o.name, owner: o.owner, version: o.ecm_version,
            boxes: o.boxes.map((b) => [...b.min, ...b.max]), meshHash: o.mesh_hash,
            meshTriangles: view_drawn_triangles(view, o.object_id),
        })) : [],
        errors: ui.errors.slice(),
        collisions: w ? w.collision_count : 0,
    };
}

window.cvre = {
    state,
    setXRPose: (pose) => {
        xr_set_override(xr, pose);
        tick();
    },
};

wake();
const params = new URLSearchParams(location.search);
ui_form(ui, true, params.get('name') ?? '');
if (params.has('name'))
    join(params.get('name'), '');
else
    ui_status(ui, 'not connected: give a name to join as a guest, and a password to join as an account');
