/*
 * session.js: one connection to the server over a WebSocket, after
 * client/session.c: the handshake (HELLO, WELCOME, JOIN, JOIN_OK), the
 * keepalive and the end, whatever ends it (a BYE, an ERROR, a frame that
 * does not decode, the socket closing). Frames of a joined session go to
 * the owner's on_frame; everything the session itself decides is told
 * in words through on_end. No reconnection: the page offers its form
 * again.
 */
import * as proto from './proto.js';

const { T, S } = proto;

/* A joined client pings this often, whatever else it sends: at least
 * every 10 s (PROTOCOL.md, section 4), and every quarter of the server's
 * idle timeout if that is shorter. The pongs give the round trip. */
const SESSION_PING_MAX_MS = 10000;
const SESSION_KEEPALIVE_FRACTION = 4;

/* What a BYE from the server means, in words. */
const BYE_WORDS = ['the server ended the session', 'the server is shutting down', 'you were removed from the server (kicked)'];

/* Words for an ERROR: the server's own text (or the code's meaning when
 * it sent none), and the code's name, which a person can look up in
 * PROTOCOL.md, section 8. */
function error_words(code, message) {
    const name = Object.keys(S).find((k) => S[k] === code);
    return `${message || proto.proto_strerror(code)} (${name || 'code ' + code})`;
}

/*
 * Opens a session to url and joins as name (a guest when password is
 * empty) with an avatar box of box metres. h holds the callbacks:
 *   on_welcome(welcome), on_join_ok(join_ok): the handshake's frames;
 *   on_frame(type, m): each decoded frame once joined (PING, PONG, BYE and
 *     ERROR are the session's own and not passed on);
 *   on_end(words, is_error): once, when the session is over.
 * Returns the session; session_send() sends a frame while it is joined.
 */
export function session_open(url, name, password, box, h) {
    const s = {
        ws: new WebSocket(url),
        state: 'connecting', /* connecting, welcomed, joined, closed */
        welcome: null,
        h,
        keepalive: 0,
        rtt_ms: null,
        ended: false,
    };
    s.ws.binaryType = 'arraybuffer';
    s.ws.onopen = () => raw_send(s, proto.proto_put_hello());
    s.ws.onmessage = (e) => on_message(s, e.data, name, password, box);
    s.ws.onerror = () => {
        if (s.state === 'connecting')
            session_end(s, `could not connect to ${url}`, true);
    };
    s.ws.onclose = (e) => session_end(s, s.state === 'joined'
        ? `the connection closed (WebSocket code ${e.code})`
        : `the connection closed before the join was done (WebSocket code ${e.code})`, true);
    return s;
}

function raw_send(s, frame) {
    if (s.ws.readyState !== WebSocket.OPEN)
        return false;
    s.ws.send(frame);
    return true;
}

/* Sends one frame (from proto.proto_put_*) if the session is joined;
 * returns whether it was handed to the socket. */
export function session_send(s, frame) {
    return s.state === 'joined' && raw_send(s, frame);
}

/* Bytes handed to the socket and not yet sent: an upload waits while
 * this is high, so that moves are not stuck behind a whole file. */
export function session_buffered(s) {
    return s.ws.bufferedAmount;
}

/* Leaves: a BYE (quit) when joined, then the close. */
export function session_quit(s) {
    if (s.state === 'joined')
        raw_send(s, proto.proto_put_bye(0));
    session_end(s, 'you left', false);
}

/*
 * Ends the session once: stops the keepalive, closes the socket (a
 * WebSocket close, never a protocol frame: a client that cannot decode
 * what it got says nothing more) and tells the owner why.
 */
function session_end(s, words, is_error) {
    if (s.ended)
        return;
    s.ended = true;
    s.state = 'closed';
    clearInterval(s.keepalive);
    if (s.ws.readyState === WebSocket.CONNECTING || s.ws.readyState === WebSocket.OPEN)
        s.ws.close(1000);
    s.h.on_end(words, is_error);
}

function on_message(s, data, name, password, box) {
    if (s.ended)
        return;
    if (!(data instanceof ArrayBuffer)) {
        session_end(s, 'the server sent a text message, which this protocol never uses', true);
        return;
    }
    const d = proto.proto_decode(data);
    if (d.status !== S.OK) {
        session_end(s, `the server sent a ${proto.proto_type_name(d.type)} frame that does not decode ` +
            `(${proto.proto_strerror(d.status)}); disconnected`, true);
        return;
    }
    const m = d.m;
    if (d.type === T.ERROR) {
        session_end(s, `the server refused: ${error_words(m.code, m.message)}`, true);
        return;
    }
    if (d.type === T.BYE) {
        session_end(s, BYE_WORDS[m.reason], m.reason !== 0);
        return;
    }
    if (s.state === 'connecting' && d.type === T.WELCOME) {
        if (m.version !== proto.PROTO_VERSION) {
            session_end(s, `the server speaks protocol version ${m.version}, this page ${proto.PROTO_VERSION}`, true);
            return;
        }
        s.state = 'welcomed';
        s.welcome = m;
        s.h.on_welcome(m);
        raw_send(s, proto.proto_put_join(name, box, password));
        return;
    }
    if (s.state === 'welcomed' && d.type === T.JOIN_OK) {
        s.state = 'joined';
        const every = Math.min(SESSION_PING_MAX_MS, s.welcome.idle_timeout_ms / SESSION_KEEPALIVE_FRACTION);
        s.keepalive = setInterval(() => raw_send(s, proto.proto_put_ping(BigInt(Math.max(1, Math.floor(performance.now()))))),
            every);
        s.h.on_join_ok(m);
        return;
    }
    if (s.state !== 'joined') {
        session_end(s, `the server sent ${proto.proto_type_name(d.type)} before the join was done; disconnected`, true);
        return;
    }
    if (d.type === T.PING) {
        raw_send(s, proto.proto_put_pong(m.stamp));
        return;
    }
    if (d.type === T.PONG) {
        /* Our stamps are milliseconds of performance.now(). */
        s.rtt_ms = performance.now() - Number(m.stamp);
        return;
    }
    s.h.on_frame(d.type, m);
}
