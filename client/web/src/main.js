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
import { world_new, world_welcome, world_joined, world_frame, world_prune } from './world.js';
import { input_new, control_new, control_step, control_correct, control_move } from './input.js';
import { view_new, view_set_bounds, view_sync, view_place_camera, view_render, view_pick,
    view_drawn_triangles, VIEW_EYE_HEIGHT } from './view.js';
import { xr_new, xr_presenting, xr_pose, xr_set_override, xr_facing, xr_stick } from './xr.js';
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
};

const canvas = document.getElementById('view');
const view = view_new(canvas);
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
            ui_status(ui, `joined as ${name}${password ? '' : ' (guest)'}, avatar ${j.avatar_id}`);
        },
        on_frame: (type, m) => world_frame(world, type, m),
        on_end: (words, is_error) => {
            page.status = 'closed';
            if (is_error)
                ui_error(ui, words);
            ui_status(ui, `session ended: ${words}`);
            ui_form(ui, true, name);
        },
    });
}

/* One frame: the pose (from XR or setXRPose), the walk, the MOVE if one is
 * due, then the scene. */
let last = performance.now();
function frame() {
    const now = performance.now();
    const dt = Math.min(0.1, (now - last) / 1000);
    last = now;
    const w = page.world, joined = page.status === 'joined';
    const in_xr = xr_presenting(view);
    if (joined) {
        const parts = xr_pose(xr, view);
        if (in_xr && parts && parts.head)
            Object.assign(input, xr_facing(parts.head.q));
        control_step(page.control, input, dt, w.welcome.max_speed, xr_stick(view));
        const pose = proto.proto_pose_fit(input.yaw, input.pitch, parts);
        const move = control_move(page.control, now, 1000 / w.welcome.tick_hz, pose);
        if (move)
            session_send(page.session, move);
    }
    if (w)
        world_prune(w, now);
    const me = page.control ? page.control.pred : [0, 0, 0];
    const box = w && w.self ? w.self.box : MAIN_AVATAR_BOX;
    view_place_camera(view, me, VIEW_EYE_HEIGHT * box[1], input.yaw, input.pitch, in_xr);
    if (w) {
        view_sync(view, w, {
            show_boxes: ui_show_boxes(), show_collisions: ui_show_collisions(),
            pose_of: proto.proto_pose_metres, dt, self_pos: me, now,
        });
        ui_users(ui, joined ? w.self.name : null, joined ? [...w.avatars.values()] : []);
        const rtt = page.session && page.session.rtt_ms !== null ? `, round trip ${page.session.rtt_ms.toFixed(0)} ms` : '';
        ui_hud(ui, joined ? `(${me.map((c) => c.toFixed(1)).join(', ')}) · ${w.objects.size} objects, ` +
            `${w.meshes.size} meshes${rtt}` : '');
    }
    view_render(view);
}
view.renderer.setAnimationLoop(frame);

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
 * (client/web/README.md gives the fields). */
function state() {
    const w = page.world, joined = page.status === 'joined';
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
    setXRPose: (pose) => xr_set_override(xr, pose),
};

const params = new URLSearchParams(location.search);
ui_form(ui, true, params.get('name') ?? '');
if (params.has('name'))
    join(params.get('name'), '');
