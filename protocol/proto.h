/*
 * proto.h: the cvre wire codec, shared by server and client.
 *
 * Pure: no I/O and no allocation. Decoding reads from a buffer the caller
 * owns and fills a message whose strings and snapshot entries point back into
 * that buffer, so a decoded message is valid only while the buffer is.
 * Encoding appends whole frames to a caller-supplied buffer through a
 * proto_writer, whose error is sticky: one check after a run of puts is
 * enough. The byte layout of every message is specified in PROTOCOL.md.
 */
#ifndef CVRE_PROTO_H
#define CVRE_PROTO_H

#include <stddef.h>
#include <stdint.h>

#define PROTO_VERSION 2
#define PROTO_MAGIC 0x45525643u /* "CVRE" read as a little-endian u32 */

/* Frame header: u32 length (bytes after the length field, i.e. the u16
 * type plus the payload), then u16 type. */
#define PROTO_HEADER_SIZE 6u
#define PROTO_LEN_MIN 2u

/* Largest length a peer may announce once joined. 64 KiB holds a snapshot of
 * 4,000 avatars, far more than an area of interest ever shows, while one
 * client's input buffer stays small. */
#ifndef PROTO_MAX_LEN
#define PROTO_MAX_LEN 65536u
#endif
/* Before join only hello and join are legal; a join with a password of
 * PROTO_PASSWORD_MAX bytes takes 179. A small cap keeps unauthenticated
 * peers cheap. */
#ifndef PROTO_MAX_LEN_PREJOIN
#define PROTO_MAX_LEN_PREJOIN 256u
#endif
#define PROTO_NAME_MAX 32u    /* display name, bytes of UTF-8 */
#define PROTO_MESSAGE_MAX 200u /* error text, bytes */
#define PROTO_TOKEN_SIZE 16u
/* Credentials a join may carry: a password of 1..PROTO_PASSWORD_MAX bytes
 * (a passphrase; the store hashes any length), or a resume token that an
 * earlier join_ok handed out. */
#define PROTO_PASSWORD_MAX 128u
#define PROTO_RESUME_TOKEN_SIZE 32u
#define PROTO_BOX_MIN 0.1f /* avatar box edge, metres */
#define PROTO_BOX_MAX 4.0f
#define PROTO_SNAPSHOT_ENTRY_SIZE 16u /* u32 id + 3 x f32 */
#define PROTO_SNAPSHOT_HEAD_SIZE 10u  /* u32 tick + u32 ack + u16 count */
/* Objects. A model file travels in chunks of at most PROTO_CHUNK_MAX bytes,
 * small enough that uploads interleave with everyone's moves; the total size
 * is capped by the server (cvre-server --max-upload). */
#define PROTO_CHUNK_MAX 16384u
#define PROTO_OBJECT_NAME_MAX 64u  /* label, e.g. the file name */
#define PROTO_FORMAT_MAX 8u        /* format hint: "obj", "glb"... */
#define PROTO_OBJECT_BOXES_MAX 1024u /* collision boxes sent per object */
#define PROTO_SCALE_MIN 0.001f     /* uniform object scale */
#define PROTO_SCALE_MAX 1000.0f
#define PROTO_BOX_ENTRY_SIZE 24u   /* 2 x vec3 */
/* Meshes. An object's mesh is named by a BLAKE2b-256 hash of its stored
 * triangles (OBJECT_INFO), asked for by object id and that hash
 * (MESH_REQUEST) and sent as one encoded mesh (proto_mesh.h) cut into
 * MESH_CHUNKs of at most PROTO_MESH_CHUNK_MAX bytes, the upload chunk's
 * size for the same reason: other frames interleave. */
#define PROTO_MESH_HASH_SIZE 32u
#define PROTO_MESH_CHUNK_MAX 16384u
#define PROTO_SNAPSHOT_MAX_ENTRIES \
    ((PROTO_MAX_LEN - 2u - PROTO_SNAPSHOT_HEAD_SIZE) / PROTO_SNAPSHOT_ENTRY_SIZE)
/* VR pose (a MOVE's optional tail, AVATAR_POSE). Positions of the head and
 * hands are int16 millimetres relative to the avatar's position: +-32 m
 * is far more than a body, and 1 mm is below what anyone can see. A
 * quaternion is four int16 components scaled by PROTO_QUAT_ONE. */
#define PROTO_QUAT_ONE 32767
/* Pitch: straight down to straight up; the binary32 nearest pi/2. */
#define PROTO_PITCH_MAX 1.5707964f
/* The head stays within 4 m of the avatar's position on each axis: the
 * largest avatar box is 4 m, and a head farther out is not on the body. */
#define PROTO_POSE_HEAD_RANGE_MM 4000
/* A hand is at most 1.5 m from the head: an adult's arm span is about
 * 1.8 m, so a hand lies within about 1 m of the head; the rest is room
 * for tracking noise and long arms. Farther is not a hand. */
#define PROTO_POSE_REACH_MM 1500
/* A quaternion's squared length must be within 1 +- 0.02: int16 rounding
 * moves it by under 1e-4, a client's float drift by less; 0.02 still
 * refuses one that was never normalised. */
#define PROTO_QUAT_NORM2_TOLERANCE 0.02
#define PROTO_POSE_PART_SIZE 14u /* 3 x i16 position + 4 x i16 quaternion */
#define PROTO_POSE_HEAD_SIZE 9u  /* f32 yaw + f32 pitch + u8 parts */

_Static_assert(PROTO_MAX_LEN_PREJOIN >= 2u + 1u + PROTO_NAME_MAX + 12u + 2u + PROTO_PASSWORD_MAX,
               "a join with a password must fit before join");
_Static_assert(PROTO_PASSWORD_MAX <= 255u && PROTO_RESUME_TOKEN_SIZE <= PROTO_PASSWORD_MAX,
               "a secret's length is a u8");
_Static_assert(PROTO_MAX_LEN <= 16u * 1024u * 1024u, "frames stay small");
_Static_assert(PROTO_SNAPSHOT_MAX_ENTRIES <= 0xffffu, "count is a u16");
_Static_assert(PROTO_CHUNK_MAX + 16u <= PROTO_MAX_LEN, "a chunk fits a frame");
_Static_assert(PROTO_MESH_CHUNK_MAX + 20u <= PROTO_MAX_LEN, "a mesh chunk fits a frame");
_Static_assert(128u + PROTO_OBJECT_BOXES_MAX * PROTO_BOX_ENTRY_SIZE <= PROTO_MAX_LEN, "boxes fit a frame");

/* Message types. Direction: C = client to server, S = server to client. */
enum proto_type {
    PROTO_HELLO = 1,         /* C */
    PROTO_WELCOME = 2,       /* S */
    PROTO_JOIN = 3,          /* C */
    PROTO_JOIN_OK = 4,       /* S */
    PROTO_MOVE = 5,          /* C */
    PROTO_SNAPSHOT = 6,      /* S */
    PROTO_AVATAR_JOINED = 7, /* S */
    PROTO_AVATAR_LEFT = 8,   /* S */
    PROTO_ERROR = 9,         /* S */
    PROTO_PING = 10,         /* C or S; the other side answers pong */
    PROTO_PONG = 11,         /* C or S */
    PROTO_BYE = 12,          /* C or S */
    PROTO_AVATAR_POSE = 13,  /* S: an avatar's facing, head and hands */
    PROTO_OBJECT_UPLOAD_BEGIN = 32, /* C */
    PROTO_OBJECT_UPLOAD_CHUNK = 33, /* C */
    PROTO_OBJECT_UPLOAD_END = 34,   /* C: the upload is complete; place it */
    PROTO_OBJECT_PLACE = 35,        /* C: move, turn or rescale an object */
    PROTO_OBJECT_REMOVE = 37,       /* C */
    PROTO_OBJECT_INFO = 38,         /* S: an object, its transform and boxes */
    PROTO_OBJECT_REMOVED = 39,      /* S */
    PROTO_OBJECT_REJECTED = 40,     /* S: a request refused; the connection stays */
    PROTO_MESH_REQUEST = 41,        /* C: send me this object's mesh */
    PROTO_MESH_CHUNK = 42,          /* S: a piece of an encoded mesh */
    PROTO_COLLISION = 48,           /* S: your avatar was blocked */
    /* Reserved for the issues that follow; not decodable yet. */
    PROTO_RESERVED_FIRST = 36,
    PROTO_OBJECT_MOVE = 36,
    PROTO_ECM_UPDATE = 49,
    PROTO_ADMIN_REQUEST = 64,
    PROTO_ADMIN_REPLY = 65,
    PROTO_RESERVED_LAST = 79
};

/* Status codes. 0 and 1 are local results; codes from 16 up are also error
 * codes on the wire (proto_error.code). */
enum proto_status {
    PROTO_OK = 0,
    PROTO_INCOMPLETE = 1, /* not a whole frame yet: read more */

    PROTO_ERR_FRAME_EMPTY = 16,    /* length < 2: no room for the type */
    PROTO_ERR_FRAME_TOO_LONG = 17, /* length over the cap in force */
    PROTO_ERR_UNKNOWN_TYPE = 18,   /* type not defined, or reserved */
    PROTO_ERR_SHORT = 19,          /* payload shorter than the layout */
    PROTO_ERR_TRAILING = 20,       /* bytes left after the layout */
    PROTO_ERR_BAD_STRING = 21,     /* string past the end, too long, or invalid */
    PROTO_ERR_NOT_FINITE = 22,     /* NaN or infinite number */
    PROTO_ERR_BAD_VALUE = 23,      /* a field out of its range */
    PROTO_ERR_BAD_MAGIC = 24,      /* hello without "CVRE" */
    PROTO_ERR_VERSION = 25,        /* protocol version not supported */
    PROTO_ERR_UNEXPECTED = 26,     /* message not legal in this state or direction */
    PROTO_ERR_ALREADY_JOINED = 27,
    PROTO_ERR_TRUNCATED = 28,      /* peer closed in the middle of a frame */
    PROTO_ERR_TIMEOUT = 29,        /* handshake, idle or partial-frame timeout */
    PROTO_ERR_SERVER_FULL = 30,
    PROTO_ERR_BAD_SEQ = 32,        /* move sequence did not increase (31 and 33 are reserved) */
    PROTO_ERR_INTERNAL = 34,
    /* Sent in OBJECT_REJECTED, which does not close the connection. */
    PROTO_ERR_UPLOAD = 35,         /* upload refused: size, sequence, too many at once */
    PROTO_ERR_IMPORT = 36,         /* the file is not a model the importer can read */
    PROTO_ERR_NO_OBJECT = 37,      /* no such object */
    PROTO_ERR_NOT_OWNER = 38,      /* only the owner (or an admin) may place or remove it */
    PROTO_ERR_GUEST = 39,          /* guests may walk and look, not change the world */
    /* Sent in ERROR before a close. */
    PROTO_ERR_AUTH = 40,           /* wrong name, password or token; or a guest took an account's name */
    PROTO_ERR_AUTH_REQUIRED = 41,  /* this server admits accounts only */
    PROTO_ERR_RATE_LIMITED = 42,   /* too many logins or connections from this address */
    PROTO_ERR_PLACEMENT = 43,      /* the object would not fit: past the world, too large, not finite */
    PROTO_ERR_STALE_MESH = 44      /* the mesh asked for is not the object's (its hash differs) */
};

/* What a join proves (proto_join.credential). */
enum proto_credential { PROTO_CRED_NONE = 0, PROTO_CRED_PASSWORD = 1, PROTO_CRED_TOKEN = 2 };

/* Why an avatar left a client's view (proto_avatar_left.reason). */
enum proto_left_reason { PROTO_LEFT_OUT_OF_RANGE = 0, PROTO_LEFT_DISCONNECTED = 1 };

/* Why a side says bye (proto_bye.reason). */
enum proto_bye_reason { PROTO_BYE_QUIT = 0, PROTO_BYE_SHUTDOWN = 1, PROTO_BYE_KICKED = 2 };

/* A string inside a frame: len bytes at ptr, not NUL-terminated. */
typedef struct proto_str {
    const char *ptr;
    uint32_t len;
} proto_str;

typedef struct proto_hello {
    uint32_t magic;
    uint16_t version;
} proto_hello;

typedef struct proto_welcome {
    uint16_t version;
    uint64_t session_id;
    uint8_t token[PROTO_TOKEN_SIZE];
    uint16_t tick_hz;
    float aoi_radius;
    float max_speed;
    float world_min[3];
    float world_max[3];
    uint32_t idle_timeout_ms; /* the server closes a connection silent this long */
} proto_welcome;

/* A join: a guest's wanted display name, or an account's name with its
 * password or a resume token. On the wire the credential is an optional
 * tail (u8 kind, u8 length, the bytes), absent for a guest. */
typedef struct proto_join {
    proto_str name;
    float box[3];       /* avatar box size x, y, z in metres */
    uint8_t credential; /* enum proto_credential */
    const uint8_t *secret; /* password or token bytes, into the payload */
    uint32_t secret_len;   /* 1..PROTO_PASSWORD_MAX; PROTO_RESUME_TOKEN_SIZE for a token */
} proto_join;

typedef struct proto_join_ok {
    uint32_t avatar_id;
    float pos[3]; /* spawn position: centre of the box's bottom face */
    float box[3];
    /* An account's join: a new resume token for the next one (tokens are
     * used once). On the wire an optional tail; absent for a guest. */
    uint8_t has_token;
    uint8_t token[PROTO_RESUME_TOKEN_SIZE];
} proto_join_ok;

/* The parts of a pose (proto_pose.parts): the head, and the hands, which
 * come only with the head. */
enum proto_pose_part { PROTO_POSE_HEAD = 0, PROTO_POSE_LEFT = 1, PROTO_POSE_RIGHT = 2, PROTO_POSE_PARTS = 3 };
#define PROTO_POSE_HAS(p, part) (((p)->parts >> (part)) & 1u)

/* Where an avatar looks, and its tracked head and hands. */
typedef struct proto_pose {
    float yaw;     /* radians about +y, finite */
    float pitch;   /* radians, in [-PROTO_PITCH_MAX, PROTO_PITCH_MAX] */
    uint8_t parts; /* bit k: part k is present (enum proto_pose_part) */
    int16_t pos[PROTO_POSE_PARTS][3]; /* mm from the avatar's position */
    int16_t rot[PROTO_POSE_PARTS][4]; /* x, y, z, w, each x PROTO_QUAT_ONE */
} proto_pose;

typedef struct proto_move {
    uint32_t seq; /* strictly increasing per connection */
    float pos[3]; /* requested position */
    uint8_t has_pose; /* on the wire an optional tail: absent, the facing stays */
    proto_pose pose;
} proto_move;

typedef struct proto_avatar_pose {
    uint32_t id;
    proto_pose pose;
} proto_avatar_pose;

/* One snapshot entry: an avatar whose position changed. */
typedef struct proto_avatar {
    uint32_t id;
    float pos[3];
} proto_avatar;

typedef struct proto_snapshot {
    uint32_t tick;
    uint32_t ack_seq; /* last move of the receiver the server applied */
    uint16_t count;
    const uint8_t *entries; /* count x PROTO_SNAPSHOT_ENTRY_SIZE bytes: proto_snapshot_entry() */
} proto_snapshot;

typedef struct proto_avatar_joined {
    uint32_t id;
    proto_str name;
    float pos[3];
    float box[3];
} proto_avatar_joined;

typedef struct proto_avatar_left {
    uint32_t id;
    uint8_t reason; /* enum proto_left_reason */
} proto_avatar_left;

typedef struct proto_error {
    uint16_t code; /* enum proto_status, >= 16 */
    proto_str message;
} proto_error;

typedef struct proto_ping {
    uint64_t stamp; /* opaque; echoed in the pong */
} proto_ping;

typedef struct proto_bye {
    uint8_t reason; /* enum proto_bye_reason */
} proto_bye;

/* Where an object stands: world = R_y(yaw) * (scale * local) + pos. */
typedef struct proto_transform {
    float pos[3];
    float yaw;   /* radians about +y, finite */
    float scale; /* uniform, in [PROTO_SCALE_MIN, PROTO_SCALE_MAX] */
} proto_transform;

enum proto_up_axis { PROTO_UP_Y = 0, PROTO_UP_Z = 1 };

typedef struct proto_upload_begin {
    uint32_t upload_id;  /* chosen by the client, non-zero, names the upload */
    uint32_t total_size; /* bytes of the model file, >= 1 */
    proto_str name;      /* 1..PROTO_OBJECT_NAME_MAX */
    proto_str format;    /* 0..PROTO_FORMAT_MAX, [a-z0-9]; empty: detect */
    uint8_t up_axis;     /* enum proto_up_axis */
    float unit_scale;    /* file units to metres, in [PROTO_SCALE_MIN, PROTO_SCALE_MAX] */
} proto_upload_begin;

typedef struct proto_upload_chunk {
    uint32_t upload_id;
    uint32_t offset;     /* bytes sent before this chunk */
    const uint8_t *data; /* 1..PROTO_CHUNK_MAX bytes, to the end of the frame */
    uint32_t len;
} proto_upload_chunk;

typedef struct proto_upload_end {
    uint32_t upload_id;
    proto_transform at;
} proto_upload_end;

typedef struct proto_object_place {
    uint32_t object_id;
    proto_transform at;
} proto_object_place;

typedef struct proto_object_info {
    uint32_t object_id;
    uint32_t upload_id; /* the upload this object came from, for its uploader; else 0 */
    proto_str owner;    /* owner's display name */
    proto_str name;
    proto_transform at;
    uint32_t ecm_version;
    uint32_t tri_count;
    uint8_t mesh_hash[PROTO_MESH_HASH_SIZE]; /* names the mesh: MESH_REQUEST */
    uint16_t box_count; /* <= PROTO_OBJECT_BOXES_MAX: proto_object_box() */
    const uint8_t *boxes;
} proto_object_info;

typedef struct proto_object_rejected {
    uint32_t request_id; /* the upload id or object id the request named */
    uint16_t code;       /* enum proto_status, >= 16 */
    proto_str message;
} proto_object_rejected;

typedef struct proto_mesh_request {
    uint32_t object_id;
    uint8_t mesh_hash[PROTO_MESH_HASH_SIZE]; /* the one OBJECT_INFO gave */
} proto_mesh_request;

/* Bytes offset..offset+len of an encoded mesh of total bytes (proto_mesh.h). */
typedef struct proto_mesh_chunk {
    uint32_t object_id;
    uint32_t total;      /* >= 1 */
    uint32_t offset;     /* offset + len <= total */
    const uint8_t *data; /* 1..PROTO_MESH_CHUNK_MAX bytes, to the end of the frame */
    uint32_t len;
} proto_mesh_chunk;

typedef struct proto_collision {
    uint32_t object_id;
    uint32_t ecm_version;
    uint16_t box_index;
    uint8_t inside;   /* 1: the avatar was already inside the box */
    float point[3];   /* contact point, world */
    float normal[3];  /* contact normal, world, unit */
} proto_collision;

typedef struct proto_msg {
    uint16_t type;
    union {
        proto_hello hello;
        proto_welcome welcome;
        proto_join join;
        proto_join_ok join_ok;
        proto_move move;
        proto_avatar_pose avatar_pose;
        proto_snapshot snapshot;
        proto_avatar_joined avatar_joined;
        proto_avatar_left avatar_left;
        proto_error error;
        proto_ping ping; /* also pong */
        proto_bye bye;
        proto_upload_begin upload_begin;
        proto_upload_chunk upload_chunk;
        proto_upload_end upload_end;
        proto_object_place object_place;
        uint32_t object_id; /* object_remove, object_removed */
        proto_object_info object_info;
        proto_object_rejected object_rejected;
        proto_collision collision;
        proto_mesh_request mesh_request;
        proto_mesh_chunk mesh_chunk;
    } u;
} proto_msg;

/* A whole frame found at the start of a buffer. */
typedef struct proto_frame {
    uint16_t type;
    const uint8_t *payload;
    uint32_t payload_len;
    size_t size; /* header + payload: bytes to consume */
} proto_frame;

/*
 * Looks for one frame at the start of buf (avail bytes). max_len is the cap
 * on the announced length in force for this peer (PROTO_MAX_LEN or
 * PROTO_MAX_LEN_PREJOIN). Returns PROTO_OK and fills *f when a whole frame is
 * there; PROTO_INCOMPLETE when more bytes are needed (the length is checked
 * against max_len as soon as its 4 bytes are in, so an oversized frame is
 * refused before it is buffered); PROTO_ERR_FRAME_EMPTY or
 * PROTO_ERR_FRAME_TOO_LONG otherwise.
 */
int proto_frame_parse(const uint8_t *buf, size_t avail, uint32_t max_len, proto_frame *f);

/*
 * Decodes the payload of a frame into *m. Checks the exact layout (no short
 * payload, no trailing bytes), string bounds and limits, finiteness of every
 * float and the ranges PROTOCOL.md gives. Returns PROTO_OK or the status that
 * names the first problem; *m is undefined on error. Pointers in *m point
 * into f->payload.
 */
int proto_decode(const proto_frame *f, proto_msg *m);

/* Entry i (< s->count) of a decoded snapshot. */
void proto_snapshot_entry(const proto_snapshot *s, uint16_t i, proto_avatar *out);
/* Box i (< o->box_count) of a decoded object info: world min and max. */
void proto_object_box(const proto_object_info *o, uint16_t i, float min[3], float max[3]);

/* Short English description of a status code; never NULL. */
const char *proto_strerror(int status);

/* Name of a BYE reason as the client's events show it ("shutdown",
 * "kicked"; "quit" for any other value). */
const char *proto_bye_name(unsigned reason);

/* Name of a message type for logs ("hello", "move"...), or "unknown". */
const char *proto_type_name(uint16_t type);

/*
 * Appends frames to buf[0..cap). On overflow err becomes PROTO_ERR_FRAME_TOO_LONG
 * and stays so; len then keeps the end of the last frame that fit whole,
 * so the buffer never holds a partial frame.
 */
typedef struct proto_writer {
    uint8_t *buf;
    size_t cap;
    size_t len;
    int err;
} proto_writer;

void proto_writer_init(proto_writer *w, uint8_t *buf, size_t cap);

/* Each put appends one whole frame. Strings longer than their limit are
 * truncated to it (at a UTF-8 character boundary for error messages). */
void proto_put_hello(proto_writer *w, const proto_hello *m);
void proto_put_welcome(proto_writer *w, const proto_welcome *m);
void proto_put_join(proto_writer *w, const proto_join *m);
void proto_put_join_ok(proto_writer *w, const proto_join_ok *m);
void proto_put_move(proto_writer *w, const proto_move *m);
void proto_put_avatar_pose(proto_writer *w, const proto_avatar_pose *m);
/* Quantizes one part of a pose: pos in metres from the avatar, q a
 * quaternion (x, y, z, w), normalised here; sets the part's bit. */
void proto_pose_set_part(proto_pose *p, unsigned part, const float pos[3], const float q[4]);
void proto_put_avatar_joined(proto_writer *w, const proto_avatar_joined *m);
void proto_put_avatar_left(proto_writer *w, const proto_avatar_left *m);
void proto_put_error(proto_writer *w, uint16_t code, const char *message);
void proto_put_ping(proto_writer *w, uint64_t stamp);
void proto_put_pong(proto_writer *w, uint64_t stamp);
void proto_put_bye(proto_writer *w, uint8_t reason);
void proto_put_upload_begin(proto_writer *w, const proto_upload_begin *m);
void proto_put_upload_chunk(proto_writer *w, const proto_upload_chunk *m);
void proto_put_upload_end(proto_writer *w, const proto_upload_end *m);
void proto_put_object_place(proto_writer *w, const proto_object_place *m);
void proto_put_object_remove(proto_writer *w, uint32_t object_id);
void proto_put_object_removed(proto_writer *w, uint32_t object_id);
void proto_put_object_rejected(proto_writer *w, uint32_t request_id, uint16_t code, const char *message);
void proto_put_collision(proto_writer *w, const proto_collision *m);
void proto_put_mesh_request(proto_writer *w, const proto_mesh_request *m);
/* A chunk of more than PROTO_MESH_CHUNK_MAX bytes is not written (FRAME_TOO_LONG). */
void proto_put_mesh_chunk(proto_writer *w, const proto_mesh_chunk *m);
/* m->boxes is ignored: the boxes come from min/max, box_count of each
 * (at most PROTO_OBJECT_BOXES_MAX; more is an error). */
void proto_put_object_info(proto_writer *w, const proto_object_info *m, const float (*min)[3], const float (*max)[3]);

/* A snapshot is built in three steps: begin, one add per entry (at most
 * PROTO_SNAPSHOT_MAX_ENTRIES), end, which patches the count and length.
 * Returns from begin the offset of the frame in w->buf, to pass to add/end. */
size_t proto_put_snapshot_begin(proto_writer *w, uint32_t tick, uint32_t ack_seq);
void proto_put_snapshot_add(proto_writer *w, size_t frame_at, const proto_avatar *a);
void proto_put_snapshot_end(proto_writer *w, size_t frame_at);

/* Exact encoded sizes, for reserving output space. */
#define PROTO_SIZE_HELLO (PROTO_HEADER_SIZE + 6u)
#define PROTO_SIZE_WELCOME (PROTO_HEADER_SIZE + 2u + 8u + PROTO_TOKEN_SIZE + 2u + 4u + 4u + 24u + 4u)
#define PROTO_SIZE_JOIN_MAX (PROTO_HEADER_SIZE + 1u + PROTO_NAME_MAX + 12u + 2u + PROTO_PASSWORD_MAX)
#define PROTO_SIZE_JOIN_OK (PROTO_HEADER_SIZE + 4u + 12u + 12u)
#define PROTO_SIZE_JOIN_OK_MAX (PROTO_SIZE_JOIN_OK + PROTO_RESUME_TOKEN_SIZE)
#define PROTO_SIZE_MOVE (PROTO_HEADER_SIZE + 4u + 12u)
#define PROTO_SIZE_POSE_MAX (PROTO_POSE_HEAD_SIZE + PROTO_POSE_PARTS * PROTO_POSE_PART_SIZE)
#define PROTO_SIZE_MOVE_MAX (PROTO_SIZE_MOVE + PROTO_SIZE_POSE_MAX)
#define PROTO_SIZE_AVATAR_POSE_MAX (PROTO_HEADER_SIZE + 4u + PROTO_SIZE_POSE_MAX)
#define PROTO_SIZE_AVATAR_JOINED_MAX (PROTO_HEADER_SIZE + 4u + 1u + PROTO_NAME_MAX + 24u)
#define PROTO_SIZE_AVATAR_LEFT (PROTO_HEADER_SIZE + 5u)
#define PROTO_SIZE_ERROR_MAX (PROTO_HEADER_SIZE + 2u + 1u + PROTO_MESSAGE_MAX)
#define PROTO_SIZE_PING (PROTO_HEADER_SIZE + 8u)
#define PROTO_SIZE_BYE (PROTO_HEADER_SIZE + 1u)
#define PROTO_SIZE_SNAPSHOT(n) (PROTO_HEADER_SIZE + PROTO_SNAPSHOT_HEAD_SIZE + (n) * PROTO_SNAPSHOT_ENTRY_SIZE)
#define PROTO_SIZE_TRANSFORM 20u
#define PROTO_SIZE_OBJECT_INFO(n) \
    (PROTO_HEADER_SIZE + 8u + 2u + PROTO_NAME_MAX + PROTO_OBJECT_NAME_MAX + PROTO_SIZE_TRANSFORM + 10u + \
     PROTO_MESH_HASH_SIZE + (n) * PROTO_BOX_ENTRY_SIZE)
#define PROTO_SIZE_OBJECT_REMOVED (PROTO_HEADER_SIZE + 4u)
#define PROTO_SIZE_OBJECT_REJECTED_MAX (PROTO_HEADER_SIZE + 4u + 2u + 1u + PROTO_MESSAGE_MAX)
#define PROTO_SIZE_MESH_REQUEST (PROTO_HEADER_SIZE + 4u + PROTO_MESH_HASH_SIZE)
#define PROTO_SIZE_MESH_CHUNK(k) (PROTO_HEADER_SIZE + 12u + (k))
#define PROTO_SIZE_COLLISION (PROTO_HEADER_SIZE + 4u + 4u + 2u + 1u + 24u)

#endif
