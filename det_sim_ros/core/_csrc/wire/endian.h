/*
 * The little-endian writers the wire units share (frames.c, wire.c).
 */
#ifndef DETSIM_WIRE_ENDIAN_H
#define DETSIM_WIRE_ENDIAN_H

#include <stdint.h>
#include <string.h>

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

#endif
