/*
 * net_limits.h: the network layer's own limits (server/net/), each with the
 * reason for its value; overridable at build time (-DNET_...=N). What an
 * endpoint decides (its output limits, its linger, its read budget and
 * input cap, its kernel send buffer) it passes to conn.h and listener.h
 * itself: the game's are in server/srv_limits.h, HTTP's in http_server.h.
 */
#ifndef CVRE_NET_LIMITS_H
#define CVRE_NET_LIMITS_H

/* A connection's input buffer starts this small and doubles on demand up to
 * the cap its endpoint passes: real traffic (moves, pings, a request head)
 * is a few dozen bytes, and 10,000 clients x 64 KiB would be 640 MiB. */
#ifndef NET_INBUF_INITIAL
#define NET_INBUF_INITIAL 128u
#endif
/* The first output buffer; it doubles on demand up to the endpoint's hard
 * limit. A tick's snapshot or a small response fits. */
#ifndef NET_OUTBUF_INITIAL
#define NET_OUTBUF_INITIAL 4096u
#endif
/* An output buffer that grew past this for a burst (a join in a world of
 * many objects, a large response) is freed once drained: 10,000 clients
 * keeping 256 KiB each would hold 2.5 GiB for nothing. A tick's snapshot
 * stays below it. */
#ifndef NET_OUTBUF_KEEP
#define NET_OUTBUF_KEEP (16u * 1024u)
#endif

/* How long a listening socket is left alone once the process is out of
 * file descriptors: the connection accept could not take stays waiting,
 * so the socket stays readable, and watching it would spin the loop (and
 * log a line a turn). Descriptors come back as connections close; nginx
 * waits half a second too. */
#ifndef NET_ACCEPT_PAUSE_MS
#define NET_ACCEPT_PAUSE_MS 500u
#endif

_Static_assert(NET_INBUF_INITIAL > 0 && NET_OUTBUF_INITIAL > 0, "doubling needs a start");
_Static_assert(NET_OUTBUF_INITIAL <= NET_OUTBUF_KEEP, "the first buffer is kept");
_Static_assert(NET_ACCEPT_PAUSE_MS >= 10 && NET_ACCEPT_PAUSE_MS <= 10000, "short enough to miss few clients");

#endif
