/* The 6-DOF loop's per-tick arithmetic, compiled: the free flight (rigid.drift_python), the held
   wrench's kick (rigid.kick_python) and the rotations and quaternion product (rotations.rotate_python, ...).

   The same IEEE operations in the same order as the Python functions (which stay the reference
   and run where this module is not built), so both give the same bits: products and sums
   left to right as Python evaluates them, no fused multiply-add (-ffp-contract=off) and sin and
   cos called one by one from the C library Python's math module calls (-fno-builtin, so the
   compiler neither merges them into sincos nor evaluates them its own way).
   tests/test_sixdof_reference.py holds both to the same digests. */

#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

static PyObject *s_x, *s_v, *s_q, *s_L, *s_body, *s_moments, *s_mass;

/* n floats of any sequence (a tuple, a list, an array) into out, as the Python twins unpack it. */
static int seq_floats(PyObject *seq, double *out, Py_ssize_t n, const char *what)
{
    PyObject *fast = PySequence_Fast(seq, what);
    if (fast == NULL)
        return -1;
    if (PySequence_Fast_GET_SIZE(fast) != n) {
        PyErr_Format(PyExc_ValueError, "%s: expected %zd values, got %zd", what, n, PySequence_Fast_GET_SIZE(fast));
        Py_DECREF(fast);
        return -1;
    }
    PyObject **items = PySequence_Fast_ITEMS(fast);
    for (Py_ssize_t i = 0; i < n; i++) {
        out[i] = PyFloat_AsDouble(items[i]);
        if (out[i] == -1.0 && PyErr_Occurred()) {
            Py_DECREF(fast);
            return -1;
        }
    }
    Py_DECREF(fast);
    return 0;
}

/* n floats of an attribute of obj (a Motion's x, v, q or L, a body's moments) into out. */
static int read_floats(PyObject *obj, PyObject *name, double *out, Py_ssize_t n)
{
    PyObject *t = PyObject_GetAttr(obj, name);
    if (t == NULL)
        return -1;
    int r = seq_floats(t, out, n, PyUnicode_AsUTF8(name));
    Py_DECREF(t);
    return r;
}

static PyObject *float_tuple(const double *v, Py_ssize_t n)
{
    PyObject *t = PyTuple_New(n);
    if (t == NULL)
        return NULL;
    for (Py_ssize_t i = 0; i < n; i++) {
        PyObject *f = PyFloat_FromDouble(v[i]);
        if (f == NULL) {
            Py_DECREF(t);
            return NULL;
        }
        PyTuple_SET_ITEM(t, i, f);
    }
    return t;
}

static int write_floats(PyObject *obj, PyObject *name, const double *v, Py_ssize_t n)
{
    PyObject *t = float_tuple(v, n);
    if (t == NULL)
        return -1;
    int r = PyObject_SetAttr(obj, name, t);
    Py_DECREF(t);
    return r;
}

/* R(q) v and R(q)^T v for a unit quaternion (x, y, z, w): rotate_python, rotate_back_python. */
static void rotate3(const double *q, const double *v, double *out)
{
    double x = q[0], y = q[1], z = q[2], w = q[3], v0 = v[0], v1 = v[1], v2 = v[2];
    double t0 = 2.0 * (y * v2 - z * v1), t1 = 2.0 * (z * v0 - x * v2), t2 = 2.0 * (x * v1 - y * v0);
    out[0] = v0 + w * t0 + y * t2 - z * t1;
    out[1] = v1 + w * t1 + z * t0 - x * t2;
    out[2] = v2 + w * t2 + x * t1 - y * t0;
}

static void rotate_back3(const double *q, const double *v, double *out)
{
    double x = q[0], y = q[1], z = q[2], w = q[3], v0 = v[0], v1 = v[1], v2 = v[2];
    double t0 = 2.0 * (z * v1 - y * v2), t1 = 2.0 * (x * v2 - z * v0), t2 = 2.0 * (y * v0 - x * v1);
    out[0] = v0 + w * t0 - y * t2 + z * t1;
    out[1] = v1 + w * t1 - z * t0 + x * t2;
    out[2] = v2 + w * t2 - x * t1 + y * t0;
}

static PyObject *rotation(PyObject *const *args, Py_ssize_t nargs, int back)
{
    double q[4], v[3], out[3];
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "rotate(q, v) takes a quaternion and a 3-vector");
        return NULL;
    }
    if (seq_floats(args[0], q, 4, "a quaternion (x, y, z, w)") || seq_floats(args[1], v, 3, "a 3-vector"))
        return NULL;
    (back ? rotate_back3 : rotate3)(q, v, out);
    return float_tuple(out, 3);
}

static PyObject *rotate(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    return rotation(args, nargs, 0);
}

static PyObject *rotate_back(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    return rotation(args, nargs, 1);
}

/* The Hamilton product a b (scalar last): quat_multiply_python. */
static PyObject *quat_multiply(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double a[4], b[4];
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "quat_multiply(a, b) takes two quaternions");
        return NULL;
    }
    if (seq_floats(args[0], a, 4, "a quaternion (x, y, z, w)") || seq_floats(args[1], b, 4, "a quaternion (x, y, z, w)"))
        return NULL;
    double ax = a[0], ay = a[1], az = a[2], aw = a[3], bx = b[0], by = b[1], bz = b[2], bw = b[3];
    double out[4] = {
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    };
    return float_tuple(out, 4);
}

/* Momenta += h (force, torque) of one body, torque (world) turned into its principal axes. */
static int kick_body(PyObject *m, PyObject *force, PyObject *torque, double h)
{
    double v[3], L[3], q[4], f[3], t[3], tb[3];
    PyObject *body = PyObject_GetAttr(m, s_body);
    if (body == NULL)
        return -1;
    PyObject *mass_obj = PyObject_GetAttr(body, s_mass);
    Py_DECREF(body);
    if (mass_obj == NULL)
        return -1;
    double mass = PyFloat_AsDouble(mass_obj);
    Py_DECREF(mass_obj);
    if (mass == -1.0 && PyErr_Occurred())
        return -1;
    if (read_floats(m, s_v, v, 3) || read_floats(m, s_L, L, 3) || read_floats(m, s_q, q, 4) ||
        seq_floats(force, f, 3, "a force") || seq_floats(torque, t, 3, "a torque"))
        return -1;
    double k = h / mass;
    rotate_back3(q, t, tb);
    double nv[3] = {v[0] + k * f[0], v[1] + k * f[1], v[2] + k * f[2]};
    double nL[3] = {L[0] + h * tb[0], L[1] + h * tb[1], L[2] + h * tb[2]};
    return write_floats(m, s_v, nv, 3) || write_floats(m, s_L, nL, 3) ? -1 : 0;
}

static PyObject *kick(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 7) {
        PyErr_SetString(PyExc_TypeError, "kick(m1, m2, f1, t1, f2, t2, h)");
        return NULL;
    }
    double h = PyFloat_AsDouble(args[6]);
    if (h == -1.0 && PyErr_Occurred())
        return NULL;
    if (kick_body(args[0], args[2], args[3], h) || kick_body(args[1], args[4], args[5], h))
        return NULL;
    Py_RETURN_NONE;
}

/* The rotation state of a drift: L in principal axes and the attitude q (x, y, z, w). */
typedef struct {
    double l1, l2, l3, qx, qy, qz, qw;
} Spin;

/* One part of the splitting: the exact flow of L_a^2 / (2 I_a) for the time whose half angle per
   unit rate is `per` (a = L_a / I_a * per), about axis 1, 2 or 3, as drift_python writes it. */
static void part(Spin *p, int axis, double i, double per)
{
    double a = (axis == 1 ? p->l1 : axis == 2 ? p->l2 : p->l3) / i * per;
    double hs = sin(a), hc = cos(a);
    double c = hc * hc - hs * hs, s = 2.0 * hs * hc;
    double qx = p->qx, qy = p->qy, qz = p->qz, qw = p->qw, u, w;
    if (axis == 1) {
        u = c * p->l2 + s * p->l3; w = c * p->l3 - s * p->l2; p->l2 = u; p->l3 = w;
        p->qx = qw * hs + qx * hc; p->qy = qy * hc + qz * hs; p->qz = qz * hc - qy * hs; p->qw = qw * hc - qx * hs;
    } else if (axis == 2) {
        u = c * p->l3 + s * p->l1; w = c * p->l1 - s * p->l3; p->l3 = u; p->l1 = w;
        p->qx = qx * hc - qz * hs; p->qy = qw * hs + qy * hc; p->qz = qz * hc + qx * hs; p->qw = qw * hc - qy * hs;
    } else {
        u = c * p->l1 + s * p->l2; w = c * p->l2 - s * p->l1; p->l1 = u; p->l2 = w;
        p->qx = qx * hc + qy * hs; p->qy = qy * hc - qx * hs; p->qz = qw * hs + qz * hc; p->qw = qw * hc - qz * hs;
    }
}

static PyObject *drift(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    if (nargs != 2) {
        PyErr_SetString(PyExc_TypeError, "drift(m, t) takes a Motion and a time");
        return NULL;
    }
    PyObject *m = args[0];
    double t = PyFloat_AsDouble(args[1]);
    if (t == -1.0 && PyErr_Occurred())
        return NULL;
    double x[3], v[3], q[4], L[3], I[3];
    PyObject *body = PyObject_GetAttr(m, s_body);
    if (body == NULL)
        return NULL;
    int bad = read_floats(body, s_moments, I, 3);
    Py_DECREF(body);
    if (bad || read_floats(m, s_x, x, 3) || read_floats(m, s_v, v, 3) || read_floats(m, s_q, q, 4) ||
        read_floats(m, s_L, L, 3))
        return NULL;

    double nx[3] = {x[0] + t * v[0], x[1] + t * v[1], x[2] + t * v[2]};
    double half = 0.5 * t, quarter = 0.25 * t;
    Spin p = {L[0], L[1], L[2], q[0], q[1], q[2], q[3]};
    part(&p, 1, I[0], quarter); /* 1-2-3-2-1: axes 1 and 2 for t/2, axis 3 for t */
    part(&p, 2, I[1], quarter);
    part(&p, 3, I[2], half);
    part(&p, 2, I[1], quarter);
    part(&p, 1, I[0], quarter);
    double n = sqrt(p.qx * p.qx + p.qy * p.qy + p.qz * p.qz + p.qw * p.qw);
    double nq[4] = {p.qx / n, p.qy / n, p.qz / n, p.qw / n};
    double nL[3] = {p.l1, p.l2, p.l3};
    if (write_floats(m, s_x, nx, 3) || write_floats(m, s_q, nq, 4) || write_floats(m, s_L, nL, 3))
        return NULL;
    Py_RETURN_NONE;
}

/* q / |q| (rotations.normalised). */
static void normalised4(const double *q, double *out)
{
    double n = sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
    out[0] = q[0] / n; out[1] = q[1] / n; out[2] = q[2] / n; out[3] = q[3] / n;
}

static void multiply4(const double *a, const double *b, double *out)
{
    double ax = a[0], ay = a[1], az = a[2], aw = a[3], bx = b[0], by = b[1], bz = b[2], bw = b[3];
    out[0] = aw * bx + ax * bw + ay * bz - az * by;
    out[1] = aw * by - ax * bz + ay * bw + az * bx;
    out[2] = aw * bz + ax * by - ay * bx + az * bw;
    out[3] = aw * bw - ax * bx - ay * by - az * bz;
}

/* A body's frames (RigidBody._frames): its interface from the CoM in principal axes, and the
   interface and principal attitudes (None where they are the identity, whose product is skipped). */
static int read_frames(PyObject *frames, double *r_p, double *q_pi, int *pi_id, double *q_bp, int *bp_id)
{
    if (!PyTuple_Check(frames) || PyTuple_GET_SIZE(frames) != 3) {
        PyErr_SetString(PyExc_TypeError, "interface: a body's frames are (r_p, q_pi or None, q_bp or None)");
        return -1;
    }
    PyObject *pi = PyTuple_GET_ITEM(frames, 1), *bp = PyTuple_GET_ITEM(frames, 2);
    *pi_id = pi == Py_None;
    *bp_id = bp == Py_None;
    return seq_floats(PyTuple_GET_ITEM(frames, 0), r_p, 3, "an interface position") ||
           (!*pi_id && seq_floats(pi, q_pi, 4, "a quaternion (x, y, z, w)")) ||
           (!*bp_id && seq_floats(bp, q_bp, 4, "a quaternion (x, y, z, w)")) ? -1 : 0;
}

/* hybrid6.published_interface's arithmetic: the principal attitudes of two published states
   (hybrid6.principal_attitude), InterfaceGeometry._place between them and its rates3. Returns
   (q1, q2, arm1, arm2, point, r, q_b, q_rel, d, d', relative angular velocity in B). */
static PyObject *interface(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double rp1[3], qpi1[4], qbp1[4], rp2[3], qpi2[4], qbp2[4];
    double x1[3], o1[4], v1[3], w1[3], x2[3], o2[4], v2[3], w2[3];
    int pi1, bp1, pi2, bp2;
    if (nargs != 10) {
        PyErr_SetString(PyExc_TypeError, "interface(frames1, frames2, x1, q1, v1, w1, x2, q2, v2, w2)");
        return NULL;
    }
    if (read_frames(args[0], rp1, qpi1, &pi1, qbp1, &bp1) || read_frames(args[1], rp2, qpi2, &pi2, qbp2, &bp2) ||
        seq_floats(args[2], x1, 3, "a position") || seq_floats(args[3], o1, 4, "a quaternion (x, y, z, w)") ||
        seq_floats(args[4], v1, 3, "a velocity") || seq_floats(args[5], w1, 3, "an angular velocity") ||
        seq_floats(args[6], x2, 3, "a position") || seq_floats(args[7], o2, 4, "a quaternion (x, y, z, w)") ||
        seq_floats(args[8], v2, 3, "a velocity") || seq_floats(args[9], w2, 3, "an angular velocity"))
        return NULL;
    double q1[4], q2[4], t[4];
    if (bp1) normalised4(o1, q1); else { multiply4(o1, qbp1, t); normalised4(t, q1); }
    if (bp2) normalised4(o2, q2); else { multiply4(o2, qbp2, t); normalised4(t, q2); }
    double a[3], b[3], point[3], r[3], qa[4], qb[4], cb[4], qrel[4], d[3], u[3], rel[3], vel[3], spin[3];
    rotate3(q1, rp1, a);
    rotate3(q2, rp2, b);
    for (int i = 0; i < 3; i++)
        point[i] = x1[i] + a[i];
    for (int i = 0; i < 3; i++)
        r[i] = point[i] - x2[i] - b[i];
    if (pi1) memcpy(qa, q1, sizeof qa); else multiply4(q1, qpi1, qa);
    if (pi2) memcpy(qb, q2, sizeof qb); else multiply4(q2, qpi2, qb);
    cb[0] = -qb[0]; cb[1] = -qb[1]; cb[2] = -qb[2]; cb[3] = qb[3];
    multiply4(cb, qa, qrel);
    rotate_back3(qb, r, d);
    double p0 = w1[0], p1 = w1[1], p2 = w1[2], s0 = w2[0], s1 = w2[1], s2 = w2[2];
    u[0] = v1[0] + p1 * a[2] - p2 * a[1] - v2[0] - s1 * b[2] + s2 * b[1] + r[1] * s2 - r[2] * s1;
    u[1] = v1[1] + p2 * a[0] - p0 * a[2] - v2[1] - s2 * b[0] + s0 * b[2] + r[2] * s0 - r[0] * s2;
    u[2] = v1[2] + p0 * a[1] - p1 * a[0] - v2[2] - s0 * b[1] + s1 * b[0] + r[0] * s1 - r[1] * s0;
    rotate_back3(qb, u, vel);
    rel[0] = p0 - s0; rel[1] = p1 - s1; rel[2] = p2 - s2;
    rotate_back3(qb, rel, spin);
    const double *parts[] = {q1, q2, a, b, point, r, qb, qrel, d, vel, spin};
    const Py_ssize_t sizes[] = {4, 4, 3, 3, 3, 3, 4, 4, 3, 3, 3};
    PyObject *out = PyTuple_New(11);
    if (out == NULL)
        return NULL;
    for (int i = 0; i < 11; i++) {
        PyObject *item = float_tuple(parts[i], sizes[i]);
        if (item == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        PyTuple_SET_ITEM(out, i, item);
    }
    return out;
}

/* The rotation vector of a unit quaternion (rotations.rotvec3_python). */
static PyObject *rotvec3(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double q[4];
    if (nargs != 1) {
        PyErr_SetString(PyExc_TypeError, "rotvec3(q) takes a quaternion");
        return NULL;
    }
    if (seq_floats(args[0], q, 4, "a quaternion (x, y, z, w)"))
        return NULL;
    double x = q[0], y = q[1], z = q[2], w = q[3];
    if (w < 0.0) {
        x = -x; y = -y; z = -z; w = -w;
    }
    double s = sqrt(x * x + y * y + z * z);
    double angle = 2.0 * atan2(s, w);
    double scale = s < 1e-8 ? 2.0 / w * (1.0 + s * s / (3.0 * w * w)) : angle / s;
    double out[3] = {scale * x, scale * y, scale * z};
    return float_tuple(out, 3);
}

/* J_l(theta)^-1 as three rows (interface6.left_jacobian_inverse3_python). */
static PyObject *left_jacobian_inverse3(PyObject *self, PyObject *const *args, Py_ssize_t nargs)
{
    double t[3];
    if (nargs != 1) {
        PyErr_SetString(PyExc_TypeError, "left_jacobian_inverse3(theta) takes a 3-vector");
        return NULL;
    }
    if (seq_floats(args[0], t, 3, "a 3-vector"))
        return NULL;
    double x = t[0], y = t[1], z = t[2];
    double sq = x * x + y * y + z * z;
    double angle = sqrt(sq);
    double c = angle < 1e-5 ? 1.0 / 12.0 + sq / 720.0 : 1.0 / sq - (1.0 + cos(angle)) / (2.0 * angle * sin(angle));
    double hx = 0.5 * x, hy = 0.5 * y, hz = 0.5 * z;
    double cxy = c * x * y, cxz = c * x * z, cyz = c * y * z;
    double rows[3][3] = {{1.0 + c * (x * x - sq), hz + cxy, cxz - hy},
                         {cxy - hz, 1.0 + c * (y * y - sq), hx + cyz},
                         {hy + cxz, cyz - hx, 1.0 + c * (z * z - sq)}};
    PyObject *out = PyTuple_New(3);
    if (out == NULL)
        return NULL;
    for (int i = 0; i < 3; i++) {
        PyObject *row = float_tuple(rows[i], 3);
        if (row == NULL) {
            Py_DECREF(out);
            return NULL;
        }
        PyTuple_SET_ITEM(out, i, row);
    }
    return out;
}

static PyMethodDef methods[] = {
    {"drift", (PyCFunction)(void (*)(void))drift, METH_FASTCALL,
     "drift(m, t): rigid.drift_python, compiled (the same bits)."},
    {"kick", (PyCFunction)(void (*)(void))kick, METH_FASTCALL,
     "kick(m1, m2, f1, t1, f2, t2, h): rigid.kick_python, compiled (the same bits)."},
    {"rotate", (PyCFunction)(void (*)(void))rotate, METH_FASTCALL,
     "rotate(q, v): rotations.rotate_python, compiled (the same bits)."},
    {"rotate_back", (PyCFunction)(void (*)(void))rotate_back, METH_FASTCALL,
     "rotate_back(q, v): rotations.rotate_back_python, compiled (the same bits)."},
    {"rotvec3", (PyCFunction)(void (*)(void))rotvec3, METH_FASTCALL,
     "rotvec3(q): rotations.rotvec3_python, compiled (the same bits)."},
    {"left_jacobian_inverse3", (PyCFunction)(void (*)(void))left_jacobian_inverse3, METH_FASTCALL,
     "left_jacobian_inverse3(theta): interface6.left_jacobian_inverse3_python, compiled (the same bits)."},
    {"interface", (PyCFunction)(void (*)(void))interface, METH_FASTCALL,
     "interface(frames1, frames2, x1, q1, v1, w1, x2, q2, v2, w2): hybrid6.published_interface's arithmetic."},
    {"quat_multiply", (PyCFunction)(void (*)(void))quat_multiply, METH_FASTCALL,
     "quat_multiply(a, b): rotations.quat_multiply_python, compiled (the same bits)."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_rigid", NULL, -1, methods, NULL, NULL, NULL, NULL};

PyMODINIT_FUNC PyInit__rigid(void)
{
    if (!(s_x = PyUnicode_InternFromString("x")) || !(s_v = PyUnicode_InternFromString("v")) ||
        !(s_q = PyUnicode_InternFromString("q")) || !(s_L = PyUnicode_InternFromString("L")) ||
        !(s_body = PyUnicode_InternFromString("body")) || !(s_moments = PyUnicode_InternFromString("_moments")) ||
        !(s_mass = PyUnicode_InternFromString("mass")))
        return NULL;
    return PyModule_Create(&module);
}
