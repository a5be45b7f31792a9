/*
 * The binding's shared helpers: arguments taken by the buffer protocol, owned copies of an
 * object's named fields (read attribute by attribute), and the checks of the types built once
 * from fields (FrameMap, SampleCodec).
 */
#include "binding/binding.h"

#include <stdlib.h>
#include <string.h>

/* ---------------------------------------------------------------- buffers */

void release_buffer(buf *b)
{
    if (b->held)
        PyBuffer_Release(&b->view);
    b->held = 0;
}

/* A C-contiguous float64 (kind 'd') or int64 (kind 'q') buffer of ``n`` items (n < 0: any). */
int get_buffer(PyObject *obj, buf *b, char kind, Py_ssize_t n, int writable,
               const char *what)
{
    int flags = PyBUF_C_CONTIGUOUS | PyBUF_FORMAT | (writable ? PyBUF_WRITABLE : 0);
    b->held = 0;
    if (PyObject_GetBuffer(obj, &b->view, flags) < 0) {
        PyErr_Format(PyExc_TypeError, "%s: expected a %sC-contiguous %s array", what,
                     writable ? "writable " : "", kind == 'd' ? "float64" : "int64");
        return -1;
    }
    b->held = 1;
    const char *f = b->view.format ? b->view.format : "B";
    if (*f == '<' || *f == '=' || *f == '@')
        f++;
    int ok = b->view.itemsize == 8 && f[1] == '\0'
             && (kind == 'd' ? f[0] == 'd' : (f[0] == 'q' || f[0] == 'l'));
    if (!ok) {
        PyErr_Format(PyExc_TypeError, "%s: expected %s items (got format '%s')", what,
                     kind == 'd' ? "float64" : "int64", b->view.format);
        release_buffer(b);
        return -1;
    }
    if (n >= 0 && b->view.len / 8 != n) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd values, got %zd", what, n,
                     b->view.len / 8);
        release_buffer(b);
        return -1;
    }
    return 0;
}

/* Acquire args[0..count-1] as ``specs`` say, into b; on failure none is held. */
int get_buffers(PyObject *const *args, const spec *specs, int count, buf *b)
{
    for (int i = 0; i < count; i++) {
        if (get_buffer(args[i], &b[i], specs[i].kind, specs[i].n, specs[i].writable,
                       specs[i].name) < 0) {
            while (i--)
                release_buffer(&b[i]);
            return -1;
        }
    }
    return 0;
}

void release_buffers(buf *b, int count)
{
    for (int i = 0; i < count; i++)
        release_buffer(&b[i]);
}

/* ---------------------------------------------------------------- owned copies */

void *keep_owned(arena *a, void *p)
{
    if (!p) {
        PyErr_NoMemory();
        return NULL;
    }
    if (a->n >= ARENA_SLOTS) {
        free(p);
        PyErr_Format(PyExc_RuntimeError, "the kernel object keeps more than %d arrays "
                     "(ARENA_SLOTS in binding.h)", ARENA_SLOTS);
        return NULL;
    }
    a->p[a->n++] = p;
    return p;
}

/* keep_owned_probe(count): keep count small arrays in a fresh arena, then free them all;
 * return count. The arena's bound is the one every kernel object has. */
PyObject *keep_owned_probe(PyObject *module, PyObject *const *args, Py_ssize_t n)
{
    (void)module;
    if (n != 1) {
        PyErr_SetString(PyExc_TypeError, "keep_owned_probe(count)");
        return NULL;
    }
    const long count = PyLong_AsLong(args[0]);
    if (count == -1 && PyErr_Occurred())
        return NULL;
    arena a = {.n = 0};
    for (long i = 0; i < count; i++)
        if (!keep_owned(&a, malloc(8))) {
            free_arena(&a);
            return NULL;
        }
    free_arena(&a);
    return PyLong_FromLong(count);
}

void free_arena(arena *a)
{
    for (int i = 0; i < a->n; i++)
        free(a->p[i]);
    a->n = 0;
}

/* Copy the named array field ``name`` of ``src`` (n items, n < 0: any) into owned memory. */
void *copy_field(arena *mem, PyObject *src, const char *name, char kind, Py_ssize_t n,
                 Py_ssize_t *got)
{
    PyObject *obj = PyObject_GetAttrString(src, name);
    if (!obj)
        return NULL;
    buf b;
    if (get_buffer(obj, &b, kind, n, 0, name) < 0) {
        Py_DECREF(obj);
        return NULL;
    }
    Py_ssize_t len = b.view.len;
    void *p = keep_owned(mem, malloc(len > 0 ? (size_t)len : 8));
    if (p) {
        memcpy(p, b.view.buf, (size_t)len);
        if (got)
            *got = len / 8;
    }
    release_buffer(&b);
    Py_DECREF(obj);
    return p;
}

int int_field(PyObject *src, const char *name, int64_t *out)
{
    PyObject *obj = PyObject_GetAttrString(src, name);
    if (!obj)
        return -1;
    long long v = PyLong_AsLongLong(obj);
    Py_DECREF(obj);
    if (v == -1 && PyErr_Occurred())
        return -1;
    *out = (int64_t)v;
    return 0;
}

int float_field(PyObject *src, const char *name, double *out)
{
    PyObject *obj = PyObject_GetAttrString(src, name);
    if (!obj)
        return -1;
    double v = PyFloat_AsDouble(obj);
    Py_DECREF(obj);
    if (v == -1.0 && PyErr_Occurred())
        return -1;
    *out = v;
    return 0;
}

/* ---------------------------------------------------------------- types built from fields */

void Built_dealloc(PyObject *self)
{
    free_arena(&((BuiltObject *)self)->mem);
    Py_TYPE(self)->tp_free(self);
}

/* The ``fields`` argument of __init__ into *src; refuses a second build (-1, error set). */
int built_fields(PyObject *self, PyObject *args, PyObject *kwds, PyObject **src)
{
    static char *kwlist[] = {"fields", NULL};
    if (!PyArg_ParseTupleAndKeywords(args, kwds, "O", kwlist, src))
        return -1;
    if (((BuiltObject *)self)->mem.n) {
        PyErr_Format(PyExc_RuntimeError, "%s is already built", Py_TYPE(self)->tp_name);
        return -1;
    }
    return 0;
}

/* 0 when built, else -1 with the error set (a method called before a successful __init__). */
int built_ready(PyObject *self)
{
    if (((BuiltObject *)self)->mem.n)
        return 0;
    PyErr_Format(PyExc_RuntimeError, "%s was not built", Py_TYPE(self)->tp_name);
    return -1;
}
