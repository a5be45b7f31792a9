/*
 * The node's I/O path in compiled code, not physics (see detsim.h for the kernel's files):
 * frames.c (marker frames) and wire.c (sample messages, MCAP records), with the little-endian
 * writers they share.
 */
#ifndef DETSIM_WIRE_H
#define DETSIM_WIRE_H

#include <stdint.h>
#include <string.h>

/* Marker frames (frames.c): the stacked polynomial map of one-coordinate cells. */
typedef struct {
    int64_t n_cells, n_values;             /* cells; drawn values per cell */
    const double *maps;                    /* (cells, values, 4): the 4 coefficients of V */
    const double *thickness_times_height;  /* n d0 l0 per cell (m^2) */
    const int64_t *coordinate;             /* each cell's q in the state vector */
    const int64_t *position;               /* byte offset of each value in the frame */
    const int64_t *stamp_position;         /* byte offset of each header stamp (sec, nanosec) */
    int64_t n_stamps;
    int64_t height, thickness;             /* indices in a cell's values */
    double min_thickness, tolerance;       /* m */
    double *values, *last;                 /* scratch: this frame's and the last written */
} ds_frame_map;

int ds_frame_update(ds_frame_map *f, const double *x, unsigned char *frame, int force,
                    int64_t stamp_ns);

/* Little-endian (CDR, MCAP) scalars at ``at``. */
static inline void ds_put_u64(unsigned char *at, uint64_t v)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    v = __builtin_bswap64(v);
#endif
    memcpy(at, &v, 8);
}

static inline void ds_put_u32(unsigned char *at, uint32_t v)
{
#if defined(__BYTE_ORDER__) && __BYTE_ORDER__ == __ORDER_BIG_ENDIAN__
    v = __builtin_bswap32(v);
#endif
    memcpy(at, &v, 4);
}

static inline void ds_put_f64(unsigned char *at, double v)
{
    uint64_t bits;
    memcpy(&bits, &v, 8);
    ds_put_u64(at, bits);
}

/* A ROS header stamp (int32 sec, uint32 nanosec) of ``stamp_ns``, as Python's divmod gives. */
static inline void ds_put_stamp(unsigned char *at, int64_t stamp_ns)
{
    int64_t sec = stamp_ns / 1000000000, nanosec = stamp_ns % 1000000000;
    if (nanosec < 0) {
        sec -= 1;
        nanosec += 1000000000;
    }
    ds_put_u32(at, (uint32_t)(int32_t)sec);
    ds_put_u32(at + 4, (uint32_t)nanosec);
}

/*
 * One sample's output messages (wire.c): every published double is read from the simulator's
 * output vector and written into the messages' CDR template, as contract.SampleEncoder does.
 */
enum { DS_WIRE_COPY = 0, DS_WIRE_FROM = 1, DS_WIRE_SCALED = 2 };   /* v; a - v; a (v - b) */
typedef struct {
    int64_t n_values, n_messages;
    const int64_t *source;      /* each double's index in the output vector */
    const int64_t *op;          /* DS_WIRE_COPY, DS_WIRE_FROM or DS_WIRE_SCALED */
    const double *a, *b;        /* their constants (y0; sign and rest) */
    const int64_t *position;    /* byte offset of each double in the messages' bytes */
    const int64_t *stamp_position;   /* byte offset of each message's header stamp */
} ds_sample_wire;

void ds_wire_encode(const ds_sample_wire *w, const double *out, int64_t stamp_ns,
                    unsigned char *messages);

/* MCAP Message record head: opcode 0x05, record length, channel, sequence, log and publish
 * time (the same); the payload follows it. */
#define DS_RECORD_HEAD 31
void ds_record_head(unsigned char *at, uint16_t channel, uint32_t sequence, uint64_t time_ns,
                    uint64_t payload_size);

#endif
