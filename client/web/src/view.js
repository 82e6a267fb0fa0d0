/*
 * view.js: the three.js scene drawn from world.js's state: the ground,
 * the objects from their meshes, the other avatars (body, name label,
 * head and hands), and, when asked, the collision boxes and the recent
 * collisions. view_sync() brings the scene in line with the world once a
 * frame; nothing else changes the scene's content.
 *
 * The camera sits in a rig at the user's avatar (its feet): outside VR
 * the camera is put at the eyes and turned by yaw and pitch; in VR three's
 * WebXR manager poses it from the headset, relative to the rig.
 */
import * as THREE from 'three';
import { WORLD_COLLISION_SHOW_MS } from './world.js';

/* Eyes of a standing adult: 1.67 m of 1.8, as the terminal client's
 * SESSION_EYE_HEIGHT. */
export const VIEW_EYE_HEIGHT = 0.93;
/* Collision markers are drawn only this close to the user, metres. */
const VIEW_COLLISION_NEAR = 30;
/* How fast drawn avatars follow the positions received (1/s). */
const VIEW_FOLLOW_RATE = 15;
const SKY = 0x9cc4e4;

/* A hue from a number, spread by the golden ratio so neighbours differ. */
function hue_of(n) {
    return (n * 0.6180339887) % 1;
}

/* Colour of the boxes of a collision-map version. */
function version_colour(version) {
    return new THREE.Color().setHSL(hue_of(version), 0.95, 0.5);
}

/* Colour of an object's surface, from its mesh hash: muted, never the
 * sky's or the ground's. */
function object_colour(hash) {
    return new THREE.Color().setHSL(hue_of(parseInt(hash.slice(0, 6), 16)), 0.35, 0.62);
}

/*
 * Makes the renderer on canvas (preserveDrawingBuffer, so a screenshot is
 * the scene), the scene, its lights and the camera rig. Returns the view.
 */
export function view_new(canvas) {
    const renderer = new THREE.WebGLRenderer({ canvas, antialias: true, preserveDrawingBuffer: true });
    renderer.setPixelRatio(Math.min(window.devicePixelRatio, 2));
    renderer.setSize(window.innerWidth, window.innerHeight, false);
    const scene = new THREE.Scene();
    scene.background = new THREE.Color(SKY);
    scene.fog = new THREE.Fog(SKY, 80, 600);
    scene.add(new THREE.HemisphereLight(0xf4f8ff, 0x5a5040, 1.6));
    const sun = new THREE.DirectionalLight(0xffffff, 2.2);
    sun.position.set(30, 60, 20);
    scene.add(sun);
    const camera = new THREE.PerspectiveCamera(70, window.innerWidth / window.innerHeight, 0.05, 2000);
    camera.rotation.order = 'YXZ';
    const rig = new THREE.Group();
    rig.add(camera);
    scene.add(rig);
    const v = {
        renderer, scene, camera, rig,
        ground: null,
        objects: new THREE.Group(),
        boxes: new THREE.Group(),
        avatars: new THREE.Group(),
        markers: new THREE.Group(),
        object_entries: new Map(), /* object id -> {info, group, mesh, boxes} */
        avatar_entries: new Map(), /* avatar id -> {group, body, label, head, hands, shown} */
        marker_entries: new Map(), /* collision record -> mesh */
        geometries: new Map(),     /* mesh hash -> BufferGeometry, for the page's life */
        raycaster: new THREE.Raycaster(),
    };
    scene.add(v.objects, v.boxes, v.avatars, v.markers);
    window.addEventListener('resize', () => {
        renderer.setSize(window.innerWidth, window.innerHeight, false);
        camera.aspect = window.innerWidth / window.innerHeight;
        camera.updateProjectionMatrix();
    });
    return v;
}

/* A tile of the ground's texture: one 2 m cell with its edge drawn, so
 * distance and motion show on the plain. */
function ground_texture(renderer, repeat_x, repeat_z) {
    const c = document.createElement('canvas');
    c.width = c.height = 128;
    const ctx = c.getContext('2d');
    ctx.fillStyle = '#7d8c6c';
    ctx.fillRect(0, 0, 128, 128);
    ctx.strokeStyle = '#66735a';
    ctx.lineWidth = 6;
    ctx.strokeRect(0, 0, 128, 128);
    const tex = new THREE.CanvasTexture(c);
    tex.colorSpace = THREE.SRGBColorSpace;
    tex.wrapS = tex.wrapT = THREE.RepeatWrapping;
    tex.repeat.set(repeat_x, repeat_z);
    tex.anisotropy = renderer.capabilities.getMaxAnisotropy();
    return tex;
}

/* The ground at y = 0 over the world's bounds, in cells of 2 m. */
export function view_set_bounds(v, min, max) {
    if (v.ground) {
        v.scene.remove(v.ground);
        v.ground.material.map.dispose();
        v.ground.material.dispose();
        v.ground.geometry.dispose();
    }
    const sx = Math.max(1, max[0] - min[0]), sz = Math.max(1, max[2] - min[2]);
    const g = new THREE.Mesh(new THREE.PlaneGeometry(sx, sz), new THREE.MeshStandardMaterial({
        map: ground_texture(v.renderer, sx / 2, sz / 2), roughness: 1,
    }));
    g.rotation.x = -Math.PI / 2;
    g.position.set((min[0] + max[0]) / 2, 0, (min[2] + max[2]) / 2);
    v.ground = g;
    v.scene.add(g);
}

/* ---- objects ----------------------------------------------------------- */

function geometry_of(v, world, hash) {
    let g = v.geometries.get(hash);
    if (!g && world.meshes.has(hash)) {
        const m = world.meshes.get(hash);
        g = new THREE.BufferGeometry();
        g.setAttribute('position', new THREE.BufferAttribute(m.positions, 3));
        g.setIndex(new THREE.BufferAttribute(m.indices, 1));
        g.computeBoundingSphere();
        g.computeBoundingBox();
        g.userData.triangles = m.tri_count;
        v.geometries.set(hash, g);
    }
    return g;
}

/* The 12 edges of each box, world coordinates, in the version's colour. */
function box_lines(info) {
    const pts = new Float32Array(info.boxes.length * 24 * 3);
    let at = 0;
    for (const b of info.boxes) {
        const c = [];
        for (let i = 0; i < 8; i++)
            c.push([i & 1 ? b.max[0] : b.min[0], i & 2 ? b.max[1] : b.min[1], i & 4 ? b.max[2] : b.min[2]]);
        for (const [a, z] of [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]]) {
            pts.set(c[a], at);
            pts.set(c[z], at + 3);
            at += 6;
        }
    }
    const g = new THREE.BufferGeometry();
    g.setAttribute('position', new THREE.BufferAttribute(pts, 3));
    return new THREE.LineSegments(g, new THREE.LineBasicMaterial({ color: version_colour(info.ecm_version) }));
}

function object_drop(v, id) {
    const e = v.object_entries.get(id);
    v.objects.remove(e.group);
    v.boxes.remove(e.boxes);
    e.boxes.geometry.dispose();
    e.boxes.material.dispose();
    if (e.mesh)
        e.mesh.material.dispose();
    v.object_entries.delete(id);
}

/* Brings the scene's objects in line with world: new, moved and removed
 * objects, meshes as they arrive, the boxes shown when show_boxes. */
export function view_sync_objects(v, world, show_boxes) {
    for (const id of [...v.object_entries.keys()])
        if (!world.objects.has(id))
            object_drop(v, id);
    for (const [id, info] of world.objects) {
        let e = v.object_entries.get(id);
        if (e && e.info !== info) {
            /* A new OBJECT_INFO: new transform or boxes. The mesh stays. */
            e.info = info;
            e.group.position.fromArray(info.at.pos);
            e.group.rotation.y = info.at.yaw;
            e.group.scale.setScalar(info.at.scale);
            v.boxes.remove(e.boxes);
            e.boxes.geometry.dispose();
            e.boxes.material.dispose();
            e.boxes = box_lines(info);
            v.boxes.add(e.boxes);
        }
        if (!e) {
            e = { info, group: new THREE.Group(), mesh: null, boxes: box_lines(info) };
            e.group.position.fromArray(info.at.pos);
            e.group.rotation.y = info.at.yaw;
            e.group.scale.setScalar(info.at.scale);
            e.group.userData.object_id = id;
            v.objects.add(e.group);
            v.boxes.add(e.boxes);
            v.object_entries.set(id, e);
        }
        if (!e.mesh) {
            const g = geometry_of(v, world, info.mesh_hash);
            if (g) {
                e.mesh = new THREE.Mesh(g, new THREE.MeshStandardMaterial({
                    color: object_colour(info.mesh_hash), roughness: 0.85, metalness: 0.05,
                    flatShading: true, side: THREE.DoubleSide,
                }));
                e.group.add(e.mesh);
            }
        }
    }
    v.boxes.visible = show_boxes;
}

/* Triangles drawn for object id's mesh; 0 until it is in the scene. */
export function view_drawn_triangles(v, id) {
    const e = v.object_entries.get(id);
    return e && e.mesh ? e.mesh.geometry.userData.triangles : 0;
}

/* ---- avatars ----------------------------------------------------------- */

/* A name label: a sprite of canvas text that always faces the camera. */
function label_sprite(text) {
    const c = document.createElement('canvas');
    const ctx = c.getContext('2d');
    const font = '600 44px system-ui, sans-serif';
    ctx.font = font;
    const w = Math.ceil(ctx.measureText(text).width) + 40;
    c.width = w;
    c.height = 64;
    ctx.font = font;
    ctx.fillStyle = 'rgba(20, 24, 32, 0.72)';
    ctx.beginPath();
    ctx.roundRect(0, 0, w, 64, 18);
    ctx.fill();
    ctx.fillStyle = '#ffffff';
    ctx.textBaseline = 'middle';
    ctx.fillText(text, 20, 34);
    const tex = new THREE.CanvasTexture(c);
    tex.colorSpace = THREE.SRGBColorSpace;
    const s = new THREE.Sprite(new THREE.SpriteMaterial({ map: tex, depthWrite: false }));
    s.scale.set(0.24 * w / 64, 0.24, 1);
    return s;
}

/* A head: a box with a nose towards its -z, which is where it looks. */
function head_mesh(colour) {
    const g = new THREE.Group();
    const mat = new THREE.MeshStandardMaterial({ color: colour, roughness: 0.6 });
    g.add(new THREE.Mesh(new THREE.BoxGeometry(0.2, 0.24, 0.22), mat));
    const nose = new THREE.Mesh(new THREE.BoxGeometry(0.05, 0.05, 0.08), new THREE.MeshStandardMaterial({ color: 0x222222 }));
    nose.position.set(0, 0, -0.14);
    g.add(nose);
    return g;
}

function hand_mesh(colour) {
    return new THREE.Mesh(new THREE.BoxGeometry(0.07, 0.05, 0.13), new THREE.MeshStandardMaterial({ color: colour }));
}

function avatar_new(v, a) {
    const colour = new THREE.Color().setHSL(hue_of(a.id), 0.6, 0.55);
    const group = new THREE.Group();
    const body = new THREE.Mesh(new THREE.BoxGeometry(a.box[0], a.box[1], a.box[2]),
        new THREE.MeshStandardMaterial({ color: colour, transparent: true, opacity: 0.55, roughness: 0.8 }));
    body.position.y = a.box[1] / 2;
    const label = label_sprite(a.name);
    label.position.y = a.box[1] + 0.35;
    const head = head_mesh(colour.clone().offsetHSL(0, 0, 0.15));
    const hands = [hand_mesh(colour), hand_mesh(colour)];
    group.add(body, label, head, ...hands);
    v.avatars.add(group);
    group.position.fromArray(a.pos);
    return { group, body, label, head, hands };
}

function avatar_drop(v, id) {
    const e = v.avatar_entries.get(id);
    v.avatars.remove(e.group);
    e.group.traverse((o) => {
        if (o.geometry)
            o.geometry.dispose();
        if (o.material) {
            if (o.material.map)
                o.material.map.dispose();
            o.material.dispose();
        }
    });
    v.avatar_entries.delete(id);
}

/* Places a drawn part at a pose part (metres and quaternion, relative to
 * the avatar's position), or hides it. */
function place_part(obj, part) {
    obj.visible = !!part;
    if (part) {
        obj.position.fromArray(part.p);
        obj.quaternion.fromArray(part.q).normalize();
    }
}

function avatars_sync(v, world, pose_of, dt) {
    for (const id of [...v.avatar_entries.keys()])
        if (!world.avatars.has(id))
            avatar_drop(v, id);
    const k = 1 - Math.exp(-VIEW_FOLLOW_RATE * dt);
    for (const [id, a] of world.avatars) {
        let e = v.avatar_entries.get(id);
        if (!e) {
            e = avatar_new(v, a);
            v.avatar_entries.set(id, e);
        }
        e.group.position.lerp(new THREE.Vector3().fromArray(a.pos), k);
        const p = a.pose ? pose_of(a.pose) : null;
        if (p && p.head) {
            place_part(e.head, p.head);
        } else {
            /* No tracked head: one at the eyes, turned by the facing. */
            e.head.visible = true;
            e.head.position.set(0, VIEW_EYE_HEIGHT * a.box[1], 0);
            e.head.rotation.set(p ? p.pitch : 0, p ? p.yaw : 0, 0, 'YXZ');
        }
        place_part(e.hands[0], p && p.left);
        place_part(e.hands[1], p && p.right);
    }
}

/* ---- collisions -------------------------------------------------------- */

/* A collision marker: a dot at the contact point and a line above it,
 * the height of the avatar, so that a contact at one's feet shows at eye
 * level too without hiding the view. Red, fading as it ages. */
function marker_new(v, c, height) {
    const mat = new THREE.MeshBasicMaterial({ color: 0xff2a1a, transparent: true, depthTest: false });
    const line_mat = new THREE.LineBasicMaterial({ color: 0xff2a1a, transparent: true, depthTest: false });
    const m = new THREE.Group();
    const dot = new THREE.Mesh(v.marker_dot || (v.marker_dot = new THREE.SphereGeometry(0.05, 12, 8)), mat);
    const post = new THREE.Line(v.marker_post || (v.marker_post = new THREE.BufferGeometry().setFromPoints(
        [new THREE.Vector3(0, 0, 0), new THREE.Vector3(0, 1, 0)])), line_mat);
    post.scale.y = height;
    dot.renderOrder = post.renderOrder = 2;
    m.add(dot, post);
    m.position.fromArray(c.point);
    m.userData.materials = [mat, line_mat];
    return m;
}

function markers_sync(v, world, show, self_pos, now) {
    const keep = new Set(show ? world.collisions : []);
    for (const [c, m] of v.marker_entries) {
        if (!keep.has(c)) {
            v.markers.remove(m);
            m.userData.materials.forEach((x) => x.dispose());
            v.marker_entries.delete(c);
        }
    }
    const height = world.self ? world.self.box[1] : 1.8;
    for (const c of keep) {
        const near = Math.hypot(c.point[0] - self_pos[0], c.point[2] - self_pos[2]) <= VIEW_COLLISION_NEAR;
        let m = v.marker_entries.get(c);
        if (!m && near) {
            m = marker_new(v, c, height);
            v.markers.add(m);
            v.marker_entries.set(c, m);
        }
        if (m)
            m.userData.materials.forEach((x) => { x.opacity = Math.max(0, 1 - (now - c.t) / WORLD_COLLISION_SHOW_MS); });
    }
}

/*
 * Brings the scene in line with world: objects (meshes as they arrive,
 * boxes shown when show_boxes), avatars (followed smoothly; pose_of turns
 * a decoded pose into metres), the collision markers when show_collisions.
 * self_pos is where the user's avatar is drawn (the predicted position).
 */
export function view_sync(v, world, opts) {
    view_sync_objects(v, world, opts.show_boxes);
    avatars_sync(v, world, opts.pose_of, opts.dt);
    markers_sync(v, world, opts.show_collisions, opts.self_pos, opts.now);
}

/* Puts the rig at the user's feet and, outside VR, the camera at the eyes
 * turned by yaw and pitch. */
export function view_place_camera(v, pos, eye, yaw, pitch, in_xr) {
    v.rig.position.fromArray(pos);
    if (!in_xr) {
        v.camera.position.set(0, eye, 0);
        v.camera.rotation.set(pitch, yaw, 0, 'YXZ');
    }
}

export function view_render(v) {
    v.renderer.render(v.scene, v.camera);
}

/*
 * Where a point of the canvas (client x, y in pixels) points in the world:
 * the first object surface along the ray, or the ground plane y = 0 if
 * that comes first; null when the ray meets neither.
 */
export function view_pick(v, x, y) {
    const r = v.renderer.domElement.getBoundingClientRect();
    const ndc = new THREE.Vector2(((x - r.left) / r.width) * 2 - 1, -((y - r.top) / r.height) * 2 + 1);
    v.raycaster.setFromCamera(ndc, v.camera);
    const hits = v.raycaster.intersectObjects(v.objects.children, true);
    const ground = v.raycaster.ray.intersectPlane(new THREE.Plane(new THREE.Vector3(0, 1, 0), 0), new THREE.Vector3());
    let best = hits.length ? hits[0].point : null;
    if (ground && (!best || ground.distanceTo(v.raycaster.ray.origin) < hits[0].distance))
        best = ground;
    return best ? [best.x, best.y, best.z] : null;
}
