/*
 * The node's I/O path in compiled code: one sample's output messages (CDR) from the simulator's
 * output vector, and MCAP Message record heads. Compiled because it runs for every sample the
 * node publishes and logs, where struct packs of Python floats would be a large share of a
 * period (docs/performance.md, 'Node I/O and real time'). The struct-pack encoder and io.log's
 * one-by-one writer stay the references the tests hold this code to, byte for byte.
 */
#include "wire/wire.h"
#include "wire/endian.h"

/*
 * Write sample ``out`` at ``stamp_ns`` into ``messages`` (every message's CDR bytes, one after
 * the other, holding the constant parts already). The doubles are computed with the same IEEE
 * operations as the contract's numpy (y0 - y; sign (v - rest)), so they are its values bit
 * for bit.
 */
void ds_wire_encode(const ds_sample_wire *w, const double *out, int64_t stamp_ns,
                    unsigned char *messages)
{
    for (int64_t i = 0; i < w->n_values; i++) {
        const double v = out[w->source[i]];
        double value = v;
        if (w->op[i] == DS_WIRE_FROM)
            value = w->a[i] - v;
        else if (w->op[i] == DS_WIRE_SCALED)
            value = w->a[i] * (v - w->b[i]);
        ds_put_f64(messages + w->position[i], value);
    }
    for (int64_t k = 0; k < w->n_messages; k++)
        ds_put_stamp(messages + w->stamp_position[k], stamp_ns);
}

void ds_record_head(unsigned char *at, uint16_t channel, uint32_t sequence, uint64_t time_ns,
                    uint64_t payload_size)
{
    at[0] = 0x05;
    ds_put_u64(at + 1, 22 + payload_size);
    at[9] = (unsigned char)(channel & 0xff);
    at[10] = (unsigned char)(channel >> 8);
    ds_put_u32(at + 11, sequence);
    ds_put_u64(at + 15, time_ns);
    ds_put_u64(at + 23, time_ns);
}
