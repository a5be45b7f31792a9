/*
 * The module det_sim_ros.core._ckernel: its types (model_type.c, stepper_type.c, io_types.c),
 * its function and its constants. binding.h lists the binding's files; physics/model.h the
 * kernel's layers.
 */
#include "binding/binding.h"

static PyMethodDef module_functions[] = {
    {"pack_records", (PyCFunction)(void (*)(void))pack_records, METH_FASTCALL,
     "pack_records(channel_ids, first_sequences, times, rows, sizes) -> (records, count): "
     "the MCAP Message records of consecutive samples (see wire.c)"},
    {"matrix_phis", (PyCFunction)(void (*)(void))matrix_phis, METH_FASTCALL,
     "matrix_phis(Z, scale, full, half): phi_k(scale Z) and phi_k(scale Z / 2) of a small "
     "matrix (see matrix_phi.c)"},
    {"keep_owned_probe", (PyCFunction)(void (*)(void))keep_owned_probe, METH_FASTCALL,
     "keep_owned_probe(count) -> count: keep count arrays in a fresh arena and free them; "
     "RuntimeError beyond ARENA_SLOTS (the bound every kernel object's arena has)"},
    {NULL}
};

static struct PyModuleDef module = {
    PyModuleDef_HEAD_INIT, "_ckernel",
    "Compiled DET-beam kernel: the model's rhs/outputs and the stepping core "
    "(see physics/model.h).",
    -1, module_functions,
};

/* STEPPER_KINDS: the names of stepping/kind.c's kinds, in its order. */
static int add_kinds(PyObject *mod)
{
    int n = 0;
    while (ds_kinds[n])
        n++;
    PyObject *names = PyTuple_New(n);
    for (int i = 0; names && i < n; i++) {
        PyObject *name = PyUnicode_FromString(ds_kinds[i]->name);
        if (!name) {
            Py_CLEAR(names);
            break;
        }
        PyTuple_SET_ITEM(names, i, name);
    }
    if (!names || PyModule_AddObject(mod, "STEPPER_KINDS", names) < 0) {
        Py_XDECREF(names);
        return -1;
    }
    return 0;
}

PyMODINIT_FUNC PyInit__ckernel(void)
{
    if (PyType_Ready(&ModelType) < 0 || PyType_Ready(&StepperType) < 0
        || PyType_Ready(&FrameMapType) < 0 || PyType_Ready(&SampleCodecType) < 0
        || PyType_Ready(&SensorReaderType) < 0)
        return NULL;
    PyObject *mod = PyModule_Create(&module);
    if (!mod)
        return NULL;
    Py_INCREF(&ModelType);
    Py_INCREF(&StepperType);
    Py_INCREF(&FrameMapType);
    Py_INCREF(&SampleCodecType);
    Py_INCREF(&SensorReaderType);
    if (PyModule_AddObject(mod, "Model", (PyObject *)&ModelType) < 0
        || PyModule_AddObject(mod, "Stepper", (PyObject *)&StepperType) < 0
        || PyModule_AddObject(mod, "FrameMap", (PyObject *)&FrameMapType) < 0
        || PyModule_AddObject(mod, "SampleCodec", (PyObject *)&SampleCodecType) < 0
        || PyModule_AddObject(mod, "SensorReader", (PyObject *)&SensorReaderType) < 0
        || PyModule_AddIntConstant(mod, "OK", DS_OK) < 0
        || PyModule_AddIntConstant(mod, "BAD_STRETCH", DS_BAD_STRETCH) < 0
        || PyModule_AddIntConstant(mod, "NON_FINITE", DS_NON_FINITE) < 0
        || PyModule_AddIntConstant(mod, "BAD_SLOPE", DS_BAD_SLOPE) < 0
        || PyModule_AddIntConstant(mod, "STEP_UNDERFLOW", DS_STEP_UNDERFLOW) < 0
        || PyModule_AddIntConstant(mod, "NO_PROGRESS", DS_NO_PROGRESS) < 0
        || PyModule_AddIntConstant(mod, "SINGULAR", DS_SINGULAR) < 0
        || PyModule_AddIntConstant(mod, "CELL_OUTPUTS", DS_CELL_OUTPUTS) < 0
        || PyModule_AddIntConstant(mod, "ARENA_SLOTS", ARENA_SLOTS) < 0
        || add_kinds(mod) < 0) {
        Py_DECREF(mod);
        return NULL;
    }
    return mod;
}
