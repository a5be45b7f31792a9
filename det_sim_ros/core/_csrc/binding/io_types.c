/*
 * The node's I/O path (frames.c, wire.c) as Python types, built once from named fields:
 *
 * FrameMap(fields)    marker frames of one-coordinate cells (det_sim_ros.ros.markers)
 * SampleCodec(fields) one sample's output messages (det_sim_ros.io.contract)
 * pack_records(...)   consecutive samples' MCAP Message records (det_sim_ros.io.log.packing)
 */
#include "binding/binding.h"

#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------- FrameMap */

typedef struct {
    PyObject_HEAD
    arena mem;                          /* first: the BuiltObject prefix */
    ds_frame_map f;
    Py_ssize_t frame_size;
} FrameMapObject;

static int FrameMap_init(FrameMapObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *src;
    if (built_fields((PyObject *)self, args, kwds, &src) < 0)
        return -1;
    ds_frame_map *f = &self->f;
    arena *mem = &self->mem;
    int64_t frame_size;
    Py_ssize_t n_cells, n_stamps;
    if (int_field(src, "n_values", &f->n_values) < 0 || int_field(src, "height", &f->height) < 0
        || int_field(src, "thickness", &f->thickness) < 0
        || int_field(src, "frame_size", &frame_size) < 0
        || float_field(src, "min_thickness", &f->min_thickness) < 0
        || float_field(src, "tolerance", &f->tolerance) < 0
        || !(f->thickness_times_height = copy_field(mem, src, "thickness_times_height", 'd',
                                                    -1, &n_cells))
        || !(f->coordinate = copy_field(mem, src, "coordinate", 'q', n_cells, NULL))
        || !(f->stamp_position = copy_field(mem, src, "stamp_position", 'q', -1, &n_stamps)))
        return -1;
    const int64_t nv = f->n_values, n = n_cells * nv;
    f->n_cells = n_cells;
    f->n_stamps = n_stamps;
    self->frame_size = (Py_ssize_t)frame_size;
    if (n_cells < 1 || nv < 1 || f->height < 0 || f->height >= nv || f->thickness < 0
        || f->thickness >= nv) {
        PyErr_SetString(PyExc_ValueError, "FrameMap: inconsistent sizes or indices");
        return -1;
    }
    if (!(f->maps = copy_field(mem, src, "maps", 'd', n * 4, NULL))
        || !(f->position = copy_field(mem, src, "position", 'q', n, NULL)))
        return -1;
    for (int64_t i = 0; i < n; i++)
        if (f->position[i] < 0 || f->position[i] + 8 > frame_size) {
            PyErr_SetString(PyExc_ValueError, "FrameMap: a value lies outside the frame");
            return -1;
        }
    for (int64_t k = 0; k < n_stamps; k++)
        if (f->stamp_position[k] < 0 || f->stamp_position[k] + 8 > frame_size) {
            PyErr_SetString(PyExc_ValueError, "FrameMap: a stamp lies outside the frame");
            return -1;
        }
    if (!(f->values = keep_owned(mem, calloc((size_t)(2 * n), sizeof(double)))))
        return -1;
    f->last = f->values + n;
    return 0;
}

static PyObject *FrameMap_update(FrameMapObject *self, PyObject *const *args, Py_ssize_t n)
{
    if (n != 4) {
        PyErr_SetString(PyExc_TypeError, "update(x, frame, force, stamp_ns)");
        return NULL;
    }
    if (built_ready((PyObject *)self) < 0)
        return NULL;
    int force = PyObject_IsTrue(args[2]);
    long long stamp = PyLong_AsLongLong(args[3]);
    if (force < 0 || (stamp == -1 && PyErr_Occurred()))
        return NULL;
    buf x;
    if (get_buffer(args[0], &x, 'd', -1, 0, "x") < 0)
        return NULL;
    const ds_frame_map *f = &self->f;
    for (int64_t c = 0; c < f->n_cells; c++)
        if (f->coordinate[c] < 0 || f->coordinate[c] >= x.view.len / 8) {
            release_buffer(&x);
            PyErr_SetString(PyExc_ValueError, "x: shorter than the model's state");
            return NULL;
        }
    Py_buffer frame;
    if (PyObject_GetBuffer(args[1], &frame, PyBUF_SIMPLE | PyBUF_WRITABLE) < 0) {
        release_buffer(&x);
        return NULL;
    }
    int written = 0;
    if (frame.len != self->frame_size)
        PyErr_Format(PyExc_ValueError, "frame: expected %zd bytes, got %zd", self->frame_size,
                     frame.len);
    else
        written = ds_frame_update(&self->f, x.view.buf, frame.buf, force, (int64_t)stamp);
    PyBuffer_Release(&frame);
    release_buffer(&x);
    if (PyErr_Occurred())
        return NULL;
    return PyBool_FromLong(written);
}

static PyMethodDef FrameMap_methods[] = {
    {"update", (PyCFunction)(void (*)(void))FrameMap_update, METH_FASTCALL,
     "update(x, frame, force, stamp_ns) -> written: the frame's values at state x; written "
     "into the frame bytes (with the stamp) when force or one moved by more than tolerance"},
    {NULL}
};

PyTypeObject FrameMapType = DS_TYPE(
    FrameMap,
    "FrameMap(fields): marker frames of one-coordinate cells, from named fields",
    FrameMapObject, FrameMap_init, Built_dealloc, FrameMap_methods, NULL);

/* ---------------------------------------------------------------- SampleCodec */

typedef struct {
    PyObject_HEAD
    arena mem;                          /* first: the BuiltObject prefix */
    ds_sample_wire w;
    unsigned char *messages;            /* the messages' bytes: template, then each sample */
    const int64_t *message_start;       /* n_messages + 1 byte offsets */
    int64_t n_outputs;                  /* the output vector is at least this long */
} SampleCodecObject;

static int SampleCodec_init(SampleCodecObject *self, PyObject *args, PyObject *kwds)
{
    PyObject *src;
    if (built_fields((PyObject *)self, args, kwds, &src) < 0)
        return -1;
    ds_sample_wire *w = &self->w;
    arena *mem = &self->mem;
    Py_ssize_t n, n_starts;
    if (!(w->source = copy_field(mem, src, "source", 'q', -1, &n))
        || !(w->op = copy_field(mem, src, "op", 'q', n, NULL))
        || !(w->a = copy_field(mem, src, "a", 'd', n, NULL))
        || !(w->b = copy_field(mem, src, "b", 'd', n, NULL))
        || !(w->position = copy_field(mem, src, "position", 'q', n, NULL))
        || !(self->message_start = copy_field(mem, src, "message_start", 'q', -1, &n_starts))
        || !(w->stamp_position = copy_field(mem, src, "stamp_position", 'q', n_starts - 1,
                                            NULL)))
        return -1;
    w->n_values = n;
    w->n_messages = n_starts - 1;
    PyObject *template = PyObject_GetAttrString(src, "template");
    if (!template)
        return -1;
    if (!PyBytes_Check(template) || w->n_messages < 1 || self->message_start[0] != 0
        || self->message_start[w->n_messages] != PyBytes_GET_SIZE(template)) {
        Py_DECREF(template);
        PyErr_SetString(PyExc_ValueError,
                        "SampleCodec: template must be the messages' bytes, message_start "
                        "their offsets from 0 to its length");
        return -1;
    }
    const int64_t size = PyBytes_GET_SIZE(template);
    self->messages = keep_owned(mem, malloc((size_t)size));
    if (!self->messages) {
        Py_DECREF(template);
        return -1;
    }
    memcpy(self->messages, PyBytes_AS_STRING(template), (size_t)size);
    Py_DECREF(template);
    for (int64_t k = 0; k < w->n_messages; k++)
        if (self->message_start[k + 1] < self->message_start[k]
            || w->stamp_position[k] < self->message_start[k]
            || w->stamp_position[k] + 8 > self->message_start[k + 1]) {
            PyErr_SetString(PyExc_ValueError, "SampleCodec: a stamp lies outside its message");
            return -1;
        }
    self->n_outputs = 0;
    for (int64_t i = 0; i < n; i++) {
        if (w->position[i] < 0 || w->position[i] + 8 > size || w->source[i] < 0
            || w->op[i] < DS_WIRE_COPY || w->op[i] > DS_WIRE_SCALED) {
            PyErr_SetString(PyExc_ValueError,
                            "SampleCodec: a value lies outside the messages, or has a bad "
                            "source or op");
            return -1;
        }
        if (w->source[i] + 1 > self->n_outputs)
            self->n_outputs = w->source[i] + 1;
    }
    return 0;
}

static PyObject *SampleCodec_encode(SampleCodecObject *self, PyObject *const *args,
                                    Py_ssize_t n)
{
    if (n != 2) {
        PyErr_SetString(PyExc_TypeError, "encode(out, stamp_ns)");
        return NULL;
    }
    if (built_ready((PyObject *)self) < 0)
        return NULL;
    long long stamp = PyLong_AsLongLong(args[1]);
    if (stamp == -1 && PyErr_Occurred())
        return NULL;
    buf out;
    if (get_buffer(args[0], &out, 'd', -1, 0, "out") < 0)
        return NULL;
    if (out.view.len / 8 < self->n_outputs) {
        release_buffer(&out);
        PyErr_Format(PyExc_ValueError, "out: expected at least %lld outputs, got %zd",
                     (long long)self->n_outputs, out.view.len / 8);
        return NULL;
    }
    ds_wire_encode(&self->w, out.view.buf, (int64_t)stamp, self->messages);
    release_buffer(&out);
    const int64_t m = self->w.n_messages;
    PyObject *result = PyList_New((Py_ssize_t)m);
    for (int64_t k = 0; result && k < m; k++) {
        const int64_t start = self->message_start[k];
        PyObject *data = PyBytes_FromStringAndSize((const char *)self->messages + start,
                                                   self->message_start[k + 1] - start);
        if (!data) {
            Py_CLEAR(result);
            break;
        }
        PyList_SET_ITEM(result, k, data);
    }
    return result;
}

static PyMethodDef SampleCodec_methods[] = {
    {"encode", (PyCFunction)(void (*)(void))SampleCodec_encode, METH_FASTCALL,
     "encode(out, stamp_ns) -> [bytes]: every output message of the sample at output "
     "vector out (float64), stamped stamp_ns"},
    {NULL}
};

PyTypeObject SampleCodecType = DS_TYPE(
    SampleCodec,
    "SampleCodec(fields): one sample's output messages, from named fields",
    SampleCodecObject, SampleCodec_init, Built_dealloc, SampleCodec_methods, NULL);

/* ---------------------------------------------------------------- pack_records */

/* An int argument in [0, limit]. */
static int bounded_int(PyObject *obj, unsigned long long limit, unsigned long long *out,
                       const char *what)
{
    unsigned long long v = PyLong_AsUnsignedLongLong(obj);
    if (v == (unsigned long long)-1 && PyErr_Occurred()) {
        PyErr_Format(PyExc_ValueError, "%s: expected an int in [0, %llu]", what, limit);
        return -1;
    }
    if (v > limit) {
        PyErr_Format(PyExc_ValueError, "%s: expected an int in [0, %llu]", what, limit);
        return -1;
    }
    *out = v;
    return 0;
}

enum { MAX_WIDTH = 64 };   /* messages per sample */

/* Each message's channel, first sequence and payload size from the sequences pack_records
 * takes; *sample_bytes: the records of one sample. */
static int read_messages(PyObject *channels, PyObject *firsts, PyObject *sizes,
                         Py_ssize_t width, unsigned long long *channel,
                         unsigned long long *first, unsigned long long *size,
                         unsigned long long *sample_bytes)
{
    *sample_bytes = 0;
    for (Py_ssize_t i = 0; i < width; i++) {
        if (bounded_int(PySequence_Fast_GET_ITEM(channels, i), 0xffff, &channel[i],
                        "channel_ids") < 0
            || bounded_int(PySequence_Fast_GET_ITEM(firsts, i), 0xffffffffULL, &first[i],
                           "first_sequences") < 0
            || bounded_int(PySequence_Fast_GET_ITEM(sizes, i), 1ULL << 40, &size[i],
                           "sizes") < 0)
            return -1;
        *sample_bytes += DS_RECORD_HEAD + size[i];
    }
    return 0;
}

/* How many of the first n rows hold ``width`` bytes payloads of ``size``. */
static Py_ssize_t rows_of_size(PyObject *rows, Py_ssize_t n, Py_ssize_t width,
                               const unsigned long long *size)
{
    Py_ssize_t count = 0;
    for (; count < n; count++) {
        PyObject *row = PySequence_Fast_GET_ITEM(rows, count);
        if (!(PyList_Check(row) || PyTuple_Check(row)) || PySequence_Fast_GET_SIZE(row) != width)
            break;
        PyObject **items = PySequence_Fast_ITEMS(row);
        Py_ssize_t i = 0;
        while (i < width && PyBytes_Check(items[i])
               && (unsigned long long)PyBytes_GET_SIZE(items[i]) == size[i])
            i++;
        if (i < width)
            break;
    }
    return count;
}

/* The records of the first ``count`` rows at ``at`` (-1 with the error set: a bad time). */
static int write_records(unsigned char *at, PyObject *times, PyObject *rows, Py_ssize_t count,
                         Py_ssize_t width, const unsigned long long *channel,
                         const unsigned long long *first, const unsigned long long *size)
{
    for (Py_ssize_t j = 0; j < count; j++) {
        unsigned long long t;
        if (bounded_int(PySequence_Fast_GET_ITEM(times, j), 0xffffffffffffffffULL, &t,
                        "times") < 0)
            return -1;
        PyObject **items = PySequence_Fast_ITEMS(PySequence_Fast_GET_ITEM(rows, j));
        for (Py_ssize_t i = 0; i < width; i++) {
            ds_record_head(at, (uint16_t)channel[i], (uint32_t)(first[i] + (unsigned long long)j),
                           t, size[i]);
            memcpy(at + DS_RECORD_HEAD, PyBytes_AS_STRING(items[i]), (size_t)size[i]);
            at += DS_RECORD_HEAD + size[i];
        }
    }
    return 0;
}

/*
 * pack_records(channel_ids, first_sequences, times, rows, sizes) -> (records, count):
 * the MCAP Message records of consecutive samples, sample j's message i on channel
 * channel_ids[i] with sequence first_sequences[i] + j at log (and publish) time times[j],
 * payload rows[j][i]. It stops before the first row whose payloads are not ``sizes`` long.
 */
PyObject *pack_records(PyObject *module, PyObject *const *args, Py_ssize_t nargs)
{
    (void)module;
    if (nargs != 5) {
        PyErr_SetString(PyExc_TypeError,
                        "pack_records(channel_ids, first_sequences, times, rows, sizes)");
        return NULL;
    }
    PyObject *channels = NULL, *firsts = NULL, *times = NULL, *rows = NULL, *sizes = NULL;
    PyObject *result = NULL, *records = NULL;
    unsigned long long channel[MAX_WIDTH], first[MAX_WIDTH], size[MAX_WIDTH], sample_bytes;
    if (!(channels = PySequence_Fast(args[0], "channel_ids: a sequence"))
        || !(firsts = PySequence_Fast(args[1], "first_sequences: a sequence"))
        || !(times = PySequence_Fast(args[2], "times: a sequence"))
        || !(rows = PySequence_Fast(args[3], "rows: a sequence"))
        || !(sizes = PySequence_Fast(args[4], "sizes: a sequence")))
        goto done;
    const Py_ssize_t width = PySequence_Fast_GET_SIZE(channels);
    Py_ssize_t n = PySequence_Fast_GET_SIZE(rows);
    if (width < 1 || width > MAX_WIDTH || PySequence_Fast_GET_SIZE(firsts) != width
        || PySequence_Fast_GET_SIZE(sizes) != width || PySequence_Fast_GET_SIZE(times) < n) {
        PyErr_SetString(PyExc_ValueError, "pack_records: channel_ids, first_sequences and "
                        "sizes must be as long (1..64), times at least as long as rows");
        goto done;
    }
    if (read_messages(channels, firsts, sizes, width, channel, first, size, &sample_bytes) < 0)
        goto done;
    const Py_ssize_t count = rows_of_size(rows, n, width, size);
    records = PyBytes_FromStringAndSize(NULL, (Py_ssize_t)(count * sample_bytes));
    if (!records || write_records((unsigned char *)PyBytes_AS_STRING(records), times, rows,
                                  count, width, channel, first, size) < 0)
        goto done;
    result = Py_BuildValue("(On)", records, count);
done:
    Py_XDECREF(records);
    Py_XDECREF(channels);
    Py_XDECREF(firsts);
    Py_XDECREF(times);
    Py_XDECREF(rows);
    Py_XDECREF(sizes);
    return result;
}
