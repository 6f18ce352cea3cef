/*
 * vlsync_wire.h - C layouts of the vlsync iceoryx2 payloads.
 *
 * Mirrors vlsync_common::wire (Rust, #[repr(C)]) field by field. Open the
 * services with the iceoryx2 C/C++ bindings using the type names below; the
 * static asserts pin every size and offset, exactly like the Rust layout tests.
 * They need C11 or C++11 (static assertions, alignof): an older C or C++ (C89/C99,
 * C++98/03) includes the header without them, as vlsync_client.h does.
 * iceoryx2 compares the service's whole message type description: the payload's
 * type variant (FixedSize), name, size and alignment, and the user header's (the
 * vlsync services have none: Rust's (), size 0, alignment 1, which a C program on
 * iceoryx2's own bindings must give too, or it gets IncompatibleTypes). It does not
 * compare fields: the ".v1" in each name is what guards them (a change of layout
 * gets a new name).
 *
 * Services (one robot per prefix):
 *   <prefix>/cam/signature, <prefix>/lidar/signature  vlsync_signature_sample  (publish-subscribe)
 *   <prefix>/signature/ready                          event: id 0 cam, 1 lidar
 *   <prefix>/offset                                   vlsync_offset_estimate   (publish-subscribe + event)
 *   <prefix>/status                                   vlsync_status            (publish-subscribe + event)
 *
 * A driver publishes each sample, then notifies <prefix>/signature/ready with its
 * stream's id; the daemon reads the samples of both streams in publish_ns order. A
 * publisher that does not notify is read at the daemon's next wake-up (the other
 * stream's notification, or 100 ms).
 *
 * Open the services; create one only if it does not exist yet (a client started
 * before the daemon), and then with the daemon's settings, which every later
 * process gets: offset and status: history 1, subscriber buffer 16, 2 publishers,
 * 16 subscribers, 32 nodes, safe overflow; their event services: 48 nodes,
 * 16 notifiers, 16 listeners. The signature services (what a C driver opens):
 * history 0, subscriber buffer 256 (or services.subscriber_buffer of the daemon's
 * configuration, if larger), 4 publishers, 4 subscribers, 16 nodes, safe overflow;
 * <prefix>/signature/ready: 48 nodes, 16 notifiers, 16 listeners.
 *
 * Times are integer nanoseconds; publish_ns fields are CLOCK_MONOTONIC.
 * Clock convention: offset = t_lidar - t_cam, so t_lidar = t_cam + offset.
 * Treat every field as untrusted. The Rust and Python clients refuse an estimate
 * unless: state and polarity are known codes; offset_s, drift, offset_std_s,
 * drift_std and peak_score are finite and both deviations >= 0; peak_ratio is not
 * NaN and >= 0 (+inf: no second peak); measured_offset_s is finite or NaN (no
 * measurement this hop), never infinite; the reserved bytes are 0. The daemon
 * refuses a signature sample with unknown flag bits or non-zero padding, and
 * rejects (and counts) non-finite or too large values and stamps that go back.
 */
#ifndef VLSYNC_WIRE_H
#define VLSYNC_WIRE_H

#include <stddef.h>
#include <stdint.h>

#define VLSYNC_SIGNATURE_SAMPLE_TYPE_NAME "vlsync.SignatureSample.v1"
#define VLSYNC_OFFSET_ESTIMATE_TYPE_NAME "vlsync.OffsetEstimate.v1"
#define VLSYNC_STATUS_TYPE_NAME "vlsync.Status.v1"

/* SignatureSample.flags */
#define VLSYNC_FLAG_FIRST 1u /* first sample after a driver (re)start */
#define VLSYNC_FLAG_SIMULATED 2u /* from a simulator (--sim, --render), not a sensor */
#define VLSYNC_KNOWN_FLAGS (VLSYNC_FLAG_FIRST | VLSYNC_FLAG_SIMULATED)

/* OffsetEstimate.state / Status.state */
#define VLSYNC_STATE_ACQUIRING 0
#define VLSYNC_STATE_TRACKING 1
#define VLSYNC_STATE_HOLDING 2
#define VLSYNC_STATE_LOST 3
#define VLSYNC_STATE_NONE 0xFF /* Status only: no estimate yet */

/* OffsetEstimate.polarity */
#define VLSYNC_POLARITY_UNKNOWN 0
#define VLSYNC_POLARITY_POSITIVE 1
#define VLSYNC_POLARITY_NEGATIVE (-1)

/* Status.rejected[stream][reason] */
#define VLSYNC_REJECT_NON_FINITE 0
#define VLSYNC_REJECT_TOO_LARGE 1
#define VLSYNC_REJECT_BACKWARDS 2
#define VLSYNC_REJECT_REPEATED 3
#define VLSYNC_REJECT_MALFORMED 4
#define VLSYNC_REJECT_REASONS 5

/* vlsync.SignatureSample.v1: 40 bytes, alignment 8 */
typedef struct vlsync_signature_sample {
    int64_t t_ns;       /*  0 sensor clock */
    double value;       /*  8 */
    uint64_t seq;       /* 16 per driver, 0 after a (re)start */
    int64_t publish_ns; /* 24 CLOCK_MONOTONIC */
    uint32_t flags;     /* 32 VLSYNC_FLAG_* */
    uint32_t reserved;  /* 36 must be 0 */
} vlsync_signature_sample;

/* vlsync.OffsetEstimate.v1: 88 bytes, alignment 8 */
typedef struct vlsync_offset_estimate {
    uint64_t seq;             /*  0 */
    int64_t t_ref_ns;         /*  8 LiDAR clock */
    double offset_s;          /* 16 t_lidar - t_cam */
    double drift;             /* 24 d offset / d t_lidar */
    double offset_std_s;      /* 32 */
    double drift_std;         /* 40 */
    double peak_score;        /* 48 */
    double peak_ratio;        /* 56 +inf when no second peak */
    double measured_offset_s; /* 64 NaN when none */
    int64_t publish_ns;       /* 72 CLOCK_MONOTONIC */
    uint8_t state;            /* 80 VLSYNC_STATE_* */
    int8_t polarity;          /* 81 VLSYNC_POLARITY_* */
    uint8_t reserved[6];      /* 82 must be 0 */
} vlsync_offset_estimate;

/* vlsync.Status.v1: 224 bytes, alignment 8; per-stream arrays: 0 cam, 1 lidar;
 * latency arrays: {p50, p99, max} in ns since the daemon started, or with
 * daemon.latency_per_period = true over the last status period only (the histograms
 * restart after each status); latency_count is how many end-to-end measurements
 * end_to_end_ns covers (processing_ns covers every valid sample, which may be more:
 * samples without a usable driver publish time) */
typedef struct vlsync_status {
    int64_t uptime_ns;                             /*   0 */
    int64_t publish_ns;                            /*   8 */
    uint64_t received[2];                          /*  16 */
    uint64_t rejected[2][VLSYNC_REJECT_REASONS];   /*  32 */
    uint64_t lost[2];                              /* 112 sequence gaps */
    uint64_t budget_overruns;                      /* 128 */
    uint64_t estimates_published;                  /* 136 */
    uint64_t events_dropped;                       /* 144 */
    uint64_t processing_ns[3];                     /* 152 */
    uint64_t end_to_end_ns[3];                     /* 176 */
    uint64_t latency_count;                        /* 200 */
    uint8_t state;                                 /* 208 VLSYNC_STATE_* or NONE */
    uint8_t degraded;                              /* 209 0 or 1 */
    uint8_t reserved[14];                          /* 210 must be 0 */
} vlsync_status;

#if defined(__cplusplus) && __cplusplus >= 201103L
#define VLSYNC_STATIC_ASSERT(c, m) static_assert(c, m)
#define VLSYNC_ALIGNOF(t) alignof(t)
#elif !defined(__cplusplus) && defined(__STDC_VERSION__) && __STDC_VERSION__ >= 201112L
#define VLSYNC_STATIC_ASSERT(c, m) _Static_assert(c, m)
#define VLSYNC_ALIGNOF(t) _Alignof(t)
#endif

#ifdef VLSYNC_STATIC_ASSERT

VLSYNC_STATIC_ASSERT(sizeof(vlsync_signature_sample) == 40, "SignatureSample size");
VLSYNC_STATIC_ASSERT(VLSYNC_ALIGNOF(vlsync_signature_sample) == 8, "SignatureSample alignment");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_signature_sample, t_ns) == 0, "SignatureSample.t_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_signature_sample, value) == 8, "SignatureSample.value");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_signature_sample, seq) == 16, "SignatureSample.seq");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_signature_sample, publish_ns) == 24, "SignatureSample.publish_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_signature_sample, flags) == 32, "SignatureSample.flags");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_signature_sample, reserved) == 36, "SignatureSample.reserved");

VLSYNC_STATIC_ASSERT(sizeof(vlsync_offset_estimate) == 88, "OffsetEstimate size");
VLSYNC_STATIC_ASSERT(VLSYNC_ALIGNOF(vlsync_offset_estimate) == 8, "OffsetEstimate alignment");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, seq) == 0, "OffsetEstimate.seq");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, t_ref_ns) == 8, "OffsetEstimate.t_ref_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, offset_s) == 16, "OffsetEstimate.offset_s");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, drift) == 24, "OffsetEstimate.drift");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, offset_std_s) == 32, "OffsetEstimate.offset_std_s");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, drift_std) == 40, "OffsetEstimate.drift_std");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, peak_score) == 48, "OffsetEstimate.peak_score");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, peak_ratio) == 56, "OffsetEstimate.peak_ratio");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, measured_offset_s) == 64, "OffsetEstimate.measured_offset_s");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, publish_ns) == 72, "OffsetEstimate.publish_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, state) == 80, "OffsetEstimate.state");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, polarity) == 81, "OffsetEstimate.polarity");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_offset_estimate, reserved) == 82, "OffsetEstimate.reserved");

VLSYNC_STATIC_ASSERT(sizeof(vlsync_status) == 224, "Status size");
VLSYNC_STATIC_ASSERT(VLSYNC_ALIGNOF(vlsync_status) == 8, "Status alignment");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, uptime_ns) == 0, "Status.uptime_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, publish_ns) == 8, "Status.publish_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, received) == 16, "Status.received");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, rejected) == 32, "Status.rejected");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, lost) == 112, "Status.lost");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, budget_overruns) == 128, "Status.budget_overruns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, estimates_published) == 136, "Status.estimates_published");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, events_dropped) == 144, "Status.events_dropped");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, processing_ns) == 152, "Status.processing_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, end_to_end_ns) == 176, "Status.end_to_end_ns");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, latency_count) == 200, "Status.latency_count");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, state) == 208, "Status.state");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, degraded) == 209, "Status.degraded");
VLSYNC_STATIC_ASSERT(offsetof(vlsync_status, reserved) == 210, "Status.reserved");
#endif /* VLSYNC_STATIC_ASSERT */
/* the helpers are this header's own: not left defined for the includer */
#undef VLSYNC_STATIC_ASSERT
#undef VLSYNC_ALIGNOF
#endif /* VLSYNC_WIRE_H */
