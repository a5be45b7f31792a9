/*
 * The Python binding's shared parts (det_sim_ros.core._ckernel):
 *
 * binding.c      buffer arguments, owned copies of named fields, the types built once from fields
 * model_type.c   Model(arrays): the named fields of det_sim_ros.physics.model.ModelArrays (read
 *                attribute by attribute: never positional), kept as C structs
 * stepper_type.c Stepper(...): a method table, transient settings and step-count control
 * io_types.c     FrameMap(fields), SampleCodec(fields) and pack_records(...): the node's I/O path
 * module.c       the module table and its init
 *
 * Arrays cross by the buffer protocol (C-contiguous float64 / int64): no numpy C API, so the
 * module builds with only a C compiler and Python's headers and works with any numpy.
 * Include this first in a binding file (Python.h must come before the system headers).
 */
#ifndef DETSIM_BINDING_H
#define DETSIM_BINDING_H

#define PY_SSIZE_T_CLEAN
#include <Python.h>

#include "physics/amplifier.h"
#include "physics/exact.h"
#include "physics/model.h"
#include "physics/outputs.h"
#include "physics/physics.h"
#include "stepping/batch.h"
#include "stepping/group.h"
#include "stepping/kind.h"
#include "stepping/linear_part.h"
#include "stepping/bdf.h"
#include "stepping/matrix_phi.h"
#include "stepping/method.h"
#include "stepping/stages.h"
#include "stepping/stepper.h"
#include "wire/frames.h"
#include "wire/wire.h"

/* Shared between the binding's files, never exported from the module nor interposable. */
#if defined(__GNUC__)
#define DS_HIDDEN __attribute__((visibility("hidden")))
#else
#define DS_HIDDEN
#endif

/* ---------------------------------------------------------------- buffer arguments */

typedef struct {
    Py_buffer view;
    int held;
} buf;

/* What one argument must be: item kind ('d' float64, 'q' int64), count (< 0: any), writable. */
typedef struct {
    char kind;
    Py_ssize_t n;
    int writable;
    const char *name;
} spec;

DS_HIDDEN void release_buffer(buf *b);
DS_HIDDEN int get_buffer(PyObject *obj, buf *b, char kind, Py_ssize_t n, int writable,
                         const char *what);
DS_HIDDEN int get_buffers(PyObject *const *args, const spec *specs, int count, buf *b);
DS_HIDDEN void release_buffers(buf *b, int count);

/* ---------------------------------------------------------------- owned copies */

/* The memory an object owns (its copies of the named fields), freed with it; a Model keeps
 * the most (~38 with the amplifier). */
enum { ARENA_SLOTS = 48 };
typedef struct {
    void *p[ARENA_SLOTS];
    int n;
} arena;

/* Keep p in the arena and return it; NULL with the Python error set when p is NULL (out of
 * memory) or the arena is full (p is freed). */
DS_HIDDEN void *keep_owned(arena *a, void *p);
DS_HIDDEN void free_arena(arena *a);
DS_HIDDEN PyObject *keep_owned_probe(PyObject *module, PyObject *const *args, Py_ssize_t n);
DS_HIDDEN void *copy_field(arena *mem, PyObject *src, const char *name, char kind,
                           Py_ssize_t n, Py_ssize_t *got);
DS_HIDDEN int int_field(PyObject *src, const char *name, int64_t *out);
DS_HIDDEN int float_field(PyObject *src, const char *name, double *out);

/* ---------------------------------------------------------------- types */

/* A Model (model_type.c); a Stepper holds one and steps its structs. */
typedef struct {
    PyObject_HEAD
    ds_model m;
    ds_work w;
    arena mem;
} ModelObject;

/* The state and input arguments of a model's methods. */
#define X_SPEC(m, w) {'d', (m)->n_state, (w), "x"}
#define U_SPEC(m, name) {'d', (m)->n_cells, 0, (name)}

/* FrameMap and SampleCodec are built once from an object's named fields into owned copies:
 * their structs start with this prefix, so one dealloc and one set of checks serve both. */
typedef struct {
    PyObject_HEAD
    arena mem;
} BuiltObject;

DS_HIDDEN void Built_dealloc(PyObject *self);

/* The type object of a kernel type: every type is a plain object with a generic new, an
 * init reading named fields, a dealloc, methods and (or NULL) getters. */
#define DS_TYPE(Name, Doc, Object, Init, Dealloc, Methods, Getset) {                    \
    PyVarObject_HEAD_INIT(NULL, 0)                                                        \
    .tp_name = "det_sim_ros.core._ckernel." #Name,                                        \
    .tp_doc = (Doc),                                                                      \
    .tp_basicsize = sizeof(Object),                                                       \
    .tp_flags = Py_TPFLAGS_DEFAULT,                                                       \
    .tp_new = PyType_GenericNew,                                                          \
    .tp_init = (initproc)(Init),                                                          \
    .tp_dealloc = (destructor)(Dealloc),                                                  \
    .tp_methods = (Methods),                                                              \
    .tp_getset = (Getset),                                                                \
}
DS_HIDDEN int built_fields(PyObject *self, PyObject *args, PyObject *kwds, PyObject **src);
DS_HIDDEN int built_ready(PyObject *self);

DS_HIDDEN extern PyTypeObject ModelType, StepperType, FrameMapType, SampleCodecType;
DS_HIDDEN extern PyTypeObject SensorReaderType;   /* sensor_type.c */
DS_HIDDEN PyObject *pack_records(PyObject *module, PyObject *const *args, Py_ssize_t nargs);
DS_HIDDEN PyObject *matrix_phis(PyObject *module, PyObject *const *args, Py_ssize_t nargs);

#endif
