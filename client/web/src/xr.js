/*
 * xr.js: WebXR. three's VRButton offers "Enter VR" where the browser has
 * WebXR (and says why not elsewhere); in VR the headset poses the camera
 * relative to the rig at the avatar's feet, and the controllers are drawn
 * as simple shapes (no controller models: those would be fetched from a
 * CDN). Each frame xr_pose() reads the viewer's and the controllers'
 * poses in the floor-level reference space, which is the avatar's own, and
 * hands them to the same pose path as cvre.setXRPose(): proto_pose_fit()
 * quantizes both.
 */
import * as THREE from 'three';
import { VRButton } from 'three/addons/webxr/VRButton.js';

/* Thumbstick deflection below this is noise, not a step. */
const XR_STICK_DEAD = 0.15;

/* A controller: a small grip block and a pointing ray. */
function controller_shape() {
    const g = new THREE.Group();
    g.add(new THREE.Mesh(new THREE.BoxGeometry(0.04, 0.04, 0.14), new THREE.MeshStandardMaterial({ color: 0x30343c })));
    const ray = new THREE.BufferGeometry().setFromPoints([new THREE.Vector3(0, 0, 0), new THREE.Vector3(0, 0, -1)]);
    g.add(new THREE.Line(ray, new THREE.LineBasicMaterial({ color: 0xffffff })));
    return g;
}

/* Enables WebXR on the view's renderer, puts the VR button into parent
 * and the controllers' shapes into the rig. Returns the XR state. */
export function xr_new(v, parent) {
    v.renderer.xr.enabled = true;
    const button = VRButton.createButton(v.renderer);
    button.id = 'enter-vr';
    parent.appendChild(button);
    for (let i = 0; i < 2; i++) {
        const grip = v.renderer.xr.getControllerGrip(i);
        grip.add(controller_shape());
        v.rig.add(grip);
    }
    return { override: null, tracked: null };
}

export function xr_presenting(v) {
    return v.renderer.xr.isPresenting;
}

function is_vec(a, n) {
    return Array.isArray(a) && a.length === n && a.every(Number.isFinite);
}

/*
 * Sets the pose to send while no XR session runs (cvre.setXRPose): null,
 * or {head, left, right}, each null/absent or {p: [x, y, z] metres from
 * the avatar's position, q: [x, y, z, w]}. Throws a TypeError for
 * anything else, so a caller's mistake is not sent.
 */
export function xr_set_override(x, pose) {
    if (pose !== null) {
        if (typeof pose !== 'object')
            throw new TypeError('setXRPose takes null or {head, left, right}');
        for (const k of ['head', 'left', 'right'])
            if (pose[k] != null && !(is_vec(pose[k].p, 3) && is_vec(pose[k].q, 4)))
                throw new TypeError(`setXRPose: ${k} must be {p: [x, y, z], q: [x, y, z, w]} of finite numbers`);
        pose = { head: pose.head || null, left: pose.left || null, right: pose.right || null };
    }
    x.override = pose;
}

function part_of(pose) {
    const t = pose.transform;
    return { p: [t.position.x, t.position.y, t.position.z], q: [t.orientation.x, t.orientation.y, t.orientation.z, t.orientation.w] };
}

/* Reads the viewer's and the controllers' poses of this XR frame, in the
 * floor-level reference space (the rig's, whose origin is the avatar's
 * position); call from the animation loop while presenting. */
export function xr_track(x, v) {
    const frame = v.renderer.xr.getFrame(), space = v.renderer.xr.getReferenceSpace();
    const viewer = frame && space ? frame.getViewerPose(space) : null;
    if (!viewer) {
        x.tracked = null;
        return;
    }
    const parts = { head: part_of(viewer), left: null, right: null };
    for (const src of frame.session.inputSources) {
        const p = src.gripSpace ? frame.getPose(src.gripSpace, space) : null;
        if (p && (src.handedness === 'left' || src.handedness === 'right'))
            parts[src.handedness] = part_of(p);
    }
    x.tracked = parts;
}

/* The tracked parts to send: the XR frame's while a session runs, else
 * the override; null when there is neither. */
export function xr_pose(x, v) {
    return xr_presenting(v) ? x.tracked : x.override;
}

/* Yaw and pitch of a head quaternion (three's YXZ order: yaw about +y,
 * then pitch about x). */
export function xr_facing(q) {
    const e = new THREE.Euler().setFromQuaternion(new THREE.Quaternion(q[0], q[1], q[2], q[3]).normalize(), 'YXZ');
    return { yaw: e.y, pitch: e.x };
}

/* The left thumbstick as [right, forward] in -1..1, or null. */
export function xr_stick(v) {
    if (!xr_presenting(v))
        return null;
    const session = v.renderer.xr.getSession();
    for (const src of session ? session.inputSources : []) {
        const a = src.gamepad ? src.gamepad.axes : null;
        if (src.handedness === 'left' && a && a.length >= 4 && Math.hypot(a[2], a[3]) > XR_STICK_DEAD)
            return [a[2], -a[3]];
    }
    return null;
}
