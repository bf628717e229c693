/* The screen of a message, compiled: what screen.bounds_check's generated Python function
   judges, judged from a spec built from the message's type (screen._screen_spec). A screen, not
   the verdict: False sends the message to the full check (encode and decode), which gives the line.
*/

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <structmember.h>
#include <math.h>

/* spec of a struct: (cls, fields); a field: (member, kind, ...), member its descriptor in cls, with kind
   0 float (ge, gt, le, lt: a float or None each), 1 int (the same bounds, as floats),
   2 bool, 3 str, 4 struct (a struct's spec), 5 tuple or 6 list (an item's field spec, name None).
   True when every value is of its field's exact type, finite and within its bounds; False
   otherwise, and for anything it does not judge (callers then run the full check). */

static int screen_value(PyObject *v, PyObject *field);

static int bounds_ok(double x, PyObject *field)
{
    PyObject *ge = PyTuple_GET_ITEM(field, 2), *gt = PyTuple_GET_ITEM(field, 3);
    PyObject *le = PyTuple_GET_ITEM(field, 4), *lt = PyTuple_GET_ITEM(field, 5);
    return (ge == Py_None || x >= PyFloat_AS_DOUBLE(ge)) && (gt == Py_None || x > PyFloat_AS_DOUBLE(gt)) &&
           (le == Py_None || x <= PyFloat_AS_DOUBLE(le)) && (lt == Py_None || x < PyFloat_AS_DOUBLE(lt));
}

static int screen_struct(PyObject *obj, PyObject *spec)
{
    if ((PyObject *)Py_TYPE(obj) != PyTuple_GET_ITEM(spec, 0))
        return 0;
    PyObject *fields = PyTuple_GET_ITEM(spec, 1);
    for (Py_ssize_t i = 0; i < PyTuple_GET_SIZE(fields); i++) {
        PyObject *field = PyTuple_GET_ITEM(fields, i), *member = PyTuple_GET_ITEM(field, 0);
        /* The field's slot read where the descriptor is a plain object slot of cls (obj is of
           exactly cls, checked above): no attribute lookup. */
        if (!Py_IS_TYPE(member, &PyMemberDescr_Type))
            return 0;
        PyMemberDef *def = ((PyMemberDescrObject *)member)->d_member;
        if (def->type != T_OBJECT_EX)
            return 0;
        PyObject *v = *(PyObject **)((char *)obj + def->offset);
        if (v == NULL || !screen_value(v, field))
            return 0;
    }
    return 1;
}

static int screen_value(PyObject *v, PyObject *field)
{
    switch (PyLong_AsLong(PyTuple_GET_ITEM(field, 1))) {
    case 0:
        return PyFloat_CheckExact(v) && isfinite(PyFloat_AS_DOUBLE(v)) && bounds_ok(PyFloat_AS_DOUBLE(v), field);
    case 1: {
        if (!PyLong_CheckExact(v))
            return 0;
        int overflow;
        long long n = PyLong_AsLongLongAndOverflow(v, &overflow);
        if (overflow || (n == -1 && PyErr_Occurred())) {
            PyErr_Clear();
            return 0;
        }
        return bounds_ok((double)n, field); /* bounds as floats: exact for the counts and ticks of msgs */
    }
    case 2:
        return PyBool_Check(v);
    case 3:
        return PyUnicode_CheckExact(v);
    case 4:
        return screen_struct(v, PyTuple_GET_ITEM(field, 2));
    case 5:
    case 6: {
        int tuple = PyLong_AsLong(PyTuple_GET_ITEM(field, 1)) == 5;
        if (tuple ? !PyTuple_CheckExact(v) : !PyList_CheckExact(v))
            return 0;
        PyObject *item = PyTuple_GET_ITEM(field, 2);
        Py_ssize_t n = tuple ? PyTuple_GET_SIZE(v) : PyList_GET_SIZE(v);
        for (Py_ssize_t i = 0; i < n; i++)
            if (!screen_value(tuple ? PyTuple_GET_ITEM(v, i) : PyList_GET_ITEM(v, i), item))
                return 0;
        return 1;
    }
    }
    return 0;
}

static PyObject *screen(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2 || !PyTuple_Check(args[0]) || PyTuple_GET_SIZE(args[0]) != 2) {
        PyErr_SetString(PyExc_TypeError, "screen(spec, message)");
        return NULL;
    }
    return PyBool_FromLong(screen_struct(args[1], args[0]));
}

static PyMethodDef methods[] = {
    {"screen", (PyCFunction)(void (*)(void))screen, METH_FASTCALL,
     "screen(spec, message): screen.bounds_check's screen, compiled."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_screen", NULL, -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__screen(void)
{
    return PyModule_Create(&module);
}
