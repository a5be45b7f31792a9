/*
 * Sample messages and MCAP message records in compiled code (wire.c): the node's I/O path,
 * not physics.
 */
#ifndef DETSIM_WIRE_WIRE_H
#define DETSIM_WIRE_WIRE_H

#include <stdint.h>

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
