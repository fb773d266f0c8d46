/* Forward kinematics, frame velocities and a damped least-squares IK step for a Drake MultibodyPlant's tree,
 * compiled: the per-step arithmetic of the sub-task environments (see tree_kinematics.py, which reads the
 * tree off the plant and documents the layouts below).
 *
 * A model is a bytes object of doubles: a header [n_links, nq, nv], then per link (parents before children)
 *   [parent (-1: world), type (0 fixed, 1 revolute, 2 prismatic, 3 quaternion floating), q start, v start,
 *    X_PF (R row-major 9, p 3), axis (3), X_MC (R 9, p 3)]
 * so that X_WB = X_WP X_PF X_FM(q) X_MC, where X_FM is the joint's motion (identity for a fixed link).
 * A frame list is a bytes object of doubles, per frame [link, X_BF (R 9, p 3)].
 *
 * Plain IEEE double arithmetic, built with -ffp-contract=off, so the numbers do not depend on the compiler's
 * choice of fused multiply-adds. */
#define PY_SSIZE_T_CLEAN
#include <Python.h>
#include <math.h>
#include <string.h>

#define HEADER 3
#define LINK 31
#define FRAME 13
#define MAX_LINKS 256
#define MAX_DOFS 64

typedef struct {
  double R[9];
  double p[3];
} Pose;

typedef struct {
  int n_links, nq, nv;
  const double *links;
} Model;

static int read_model(PyObject *bytes, Model *model) {
  if (!PyBytes_Check(bytes)) {
    PyErr_SetString(PyExc_TypeError, "_kinematics: the model must be bytes (from TreeKinematics)");
    return -1;
  }
  Py_ssize_t size = PyBytes_GET_SIZE(bytes) / (Py_ssize_t)sizeof(double);
  const double *data = (const double *)PyBytes_AS_STRING(bytes);
  if (size < HEADER || data[0] < 0 || data[0] > MAX_LINKS || size != HEADER + (Py_ssize_t)data[0] * LINK) {
    PyErr_SetString(PyExc_ValueError, "_kinematics: malformed model (rebuild it with TreeKinematics)");
    return -1;
  }
  model->n_links = (int)data[0];
  model->nq = (int)data[1];
  model->nv = (int)data[2];
  model->links = data + HEADER;
  static const int sizes[4][2] = {{0, 0}, {1, 1}, {1, 1}, {7, 6}};
  for (int i = 0; i < model->n_links; ++i) {
    const double *link = model->links + i * LINK;
    int parent = (int)link[0], type = (int)link[1], qi = (int)link[2], vi = (int)link[3];
    if (parent < -1 || parent >= i || type < 0 || type > 3 || qi < 0 || vi < 0 ||
        qi + sizes[type][0] > model->nq || vi + sizes[type][1] > model->nv) {
      PyErr_SetString(PyExc_ValueError, "_kinematics: malformed model link (rebuild it with TreeKinematics)");
      return -1;
    }
  }
  return 0;
}

static int read_frames(PyObject *bytes, const Model *model, const double **frames, int *n) {
  if (!PyBytes_Check(bytes)) {
    PyErr_SetString(PyExc_TypeError, "_kinematics: the frames must be bytes (from TreeKinematics)");
    return -1;
  }
  Py_ssize_t size = PyBytes_GET_SIZE(bytes) / (Py_ssize_t)sizeof(double);
  *frames = (const double *)PyBytes_AS_STRING(bytes);
  *n = (int)(size / FRAME);
  if (size % FRAME != 0) {
    PyErr_SetString(PyExc_ValueError, "_kinematics: malformed frame list (rebuild it with TreeKinematics)");
    return -1;
  }
  for (int i = 0; i < *n; ++i) {
    int link = (int)(*frames)[i * FRAME];
    if (link < 0 || link >= model->n_links) {
      PyErr_SetString(PyExc_ValueError, "_kinematics: a frame's link is not in the model");
      return -1;
    }
  }
  return 0;
}

/* Copies a sequence of numbers (a list, tuple or array) of length `n` into `out`. */
static int read_vector(PyObject *object, Py_ssize_t n, double *out, const char *what) {
  PyObject *sequence = PySequence_Fast(object, what);
  if (sequence == NULL) return -1;
  if (PySequence_Fast_GET_SIZE(sequence) != n) {
    PyErr_Format(PyExc_ValueError, "_kinematics: %s must have %zd entries, got %zd", what, n,
                 PySequence_Fast_GET_SIZE(sequence));
    Py_DECREF(sequence);
    return -1;
  }
  PyObject **items = PySequence_Fast_ITEMS(sequence);
  for (Py_ssize_t i = 0; i < n; ++i) {
    out[i] = PyFloat_AsDouble(items[i]);
    if (out[i] == -1.0 && PyErr_Occurred()) {
      Py_DECREF(sequence);
      return -1;
    }
  }
  Py_DECREF(sequence);
  return 0;
}

static PyObject *list_of(const double *values, Py_ssize_t n) {
  PyObject *list = PyList_New(n);
  if (list == NULL) return NULL;
  for (Py_ssize_t i = 0; i < n; ++i) {
    PyObject *item = PyFloat_FromDouble(values[i]);
    if (item == NULL) {
      Py_DECREF(list);
      return NULL;
    }
    PyList_SET_ITEM(list, i, item);
  }
  return list;
}

static void read_pose(const double *d, Pose *X) {
  memcpy(X->R, d, 9 * sizeof(double));
  memcpy(X->p, d + 9, 3 * sizeof(double));
}

/* c = a b */
static void compose(const Pose *a, const Pose *b, Pose *c) {
  Pose out;
  for (int i = 0; i < 3; ++i) {
    for (int j = 0; j < 3; ++j)
      out.R[3 * i + j] = a->R[3 * i] * b->R[j] + a->R[3 * i + 1] * b->R[3 + j] + a->R[3 * i + 2] * b->R[6 + j];
    out.p[i] = a->R[3 * i] * b->p[0] + a->R[3 * i + 1] * b->p[1] + a->R[3 * i + 2] * b->p[2] + a->p[i];
  }
  *c = out;
}

static void rotate(const double *R, const double *v, double *out) {
  for (int i = 0; i < 3; ++i) out[i] = R[3 * i] * v[0] + R[3 * i + 1] * v[1] + R[3 * i + 2] * v[2];
}

static void cross(const double *a, const double *b, double *out) {
  double x = a[1] * b[2] - a[2] * b[1], y = a[2] * b[0] - a[0] * b[2], z = a[0] * b[1] - a[1] * b[0];
  out[0] = x;
  out[1] = y;
  out[2] = z;
}

/* v += w x (a - b) */
static void add_moment(double *v, const double *w, const double *a, const double *b) {
  double d[3] = {a[0] - b[0], a[1] - b[1], a[2] - b[2]}, m[3];
  cross(w, d, m);
  for (int i = 0; i < 3; ++i) v[i] += m[i];
}

/* Rotation by `angle` about unit `axis` (Rodrigues). */
static void axis_rotation(const double *axis, double angle, double *R) {
  double x = axis[0], y = axis[1], z = axis[2], c = cos(angle), s = sin(angle), t = 1.0 - c;
  R[0] = t * x * x + c;     R[1] = t * x * y - s * z; R[2] = t * x * z + s * y;
  R[3] = t * x * y + s * z; R[4] = t * y * y + c;     R[5] = t * y * z - s * x;
  R[6] = t * x * z - s * y; R[7] = t * y * z + s * x; R[8] = t * z * z + c;
}

/* The rotation of a quaternion [w, x, y, z] of any non-zero length (as Drake's RotationMatrix(Quaternion)). */
static void quaternion_rotation(const double *q, double *R) {
  double w = q[0], x = q[1], y = q[2], z = q[3], s = 2.0 / (w * w + x * x + y * y + z * z);
  R[0] = 1.0 - s * (y * y + z * z); R[1] = s * (x * y - w * z);       R[2] = s * (x * z + w * y);
  R[3] = s * (x * y + w * z);       R[4] = 1.0 - s * (x * x + z * z); R[5] = s * (y * z - w * x);
  R[6] = s * (x * z - w * y);       R[7] = s * (y * z + w * x);       R[8] = 1.0 - s * (x * x + y * y);
}

/* The unit quaternion [w, x, y, z], w >= 0, of a rotation matrix (Shepperd's method). */
static void rotation_quaternion(const double *R, double *q) {
  double r00 = R[0], r01 = R[1], r02 = R[2], r10 = R[3], r11 = R[4], r12 = R[5], r20 = R[6], r21 = R[7],
         r22 = R[8], trace = r00 + r11 + r22, s;
  if (trace >= r00 && trace >= r11 && trace >= r22) {
    s = 2.0 * sqrt(1.0 + trace);
    q[0] = 0.25 * s; q[1] = (r21 - r12) / s; q[2] = (r02 - r20) / s; q[3] = (r10 - r01) / s;
  } else if (r00 >= r11 && r00 >= r22) {
    s = 2.0 * sqrt(1.0 + r00 - r11 - r22);
    q[0] = (r21 - r12) / s; q[1] = 0.25 * s; q[2] = (r01 + r10) / s; q[3] = (r02 + r20) / s;
  } else if (r11 >= r22) {
    s = 2.0 * sqrt(1.0 - r00 + r11 - r22);
    q[0] = (r02 - r20) / s; q[1] = (r01 + r10) / s; q[2] = 0.25 * s; q[3] = (r12 + r21) / s;
  } else {
    s = 2.0 * sqrt(1.0 - r00 - r11 + r22);
    q[0] = (r10 - r01) / s; q[1] = (r02 + r20) / s; q[2] = (r12 + r21) / s; q[3] = 0.25 * s;
  }
  if (q[0] < 0.0)
    for (int i = 0; i < 4; ++i) q[i] = -q[i];
}

/* Poses X_WB of every link, and with `v` non-NULL their spatial velocities in the world (angular w_WB,
 * translational v_WBo), from positions q and velocities v. The arrays hold n_links entries. */
static void forward(const Model *m, const double *q, const double *v, Pose *X, double (*w)[3], double (*vo)[3]) {
  static const double zero[3] = {0.0, 0.0, 0.0};
  Pose identity = {{1, 0, 0, 0, 1, 0, 0, 0, 1}, {0, 0, 0}};
  for (int i = 0; i < m->n_links; ++i) {
    const double *link = m->links + i * LINK;
    int parent = (int)link[0], type = (int)link[1], qi = (int)link[2], vi = (int)link[3];
    const double *axis = link + 16;
    const Pose *X_WP = parent < 0 ? &identity : &X[parent];
    Pose X_PF, X_MC, X_WF, X_FM, X_WM;
    read_pose(link + 4, &X_PF);
    read_pose(link + 19, &X_MC);
    compose(X_WP, &X_PF, &X_WF);
    double w_F[3], v_F[3], w_M[3], v_M[3], a_W[3];
    if (v != NULL) {
      memcpy(w_F, parent < 0 ? zero : w[parent], sizeof w_F);
      memcpy(v_F, parent < 0 ? zero : vo[parent], sizeof v_F);
      add_moment(v_F, w_F, X_WF.p, X_WP->p);
      memcpy(w_M, w_F, sizeof w_M);
      memcpy(v_M, v_F, sizeof v_M);
    }
    switch (type) {
      case 1:  /* revolute: M turns about the axis through F's origin */
        axis_rotation(axis, q[qi], X_FM.R);
        memset(X_FM.p, 0, sizeof X_FM.p);
        compose(&X_WF, &X_FM, &X_WM);
        if (v != NULL) {
          rotate(X_WF.R, axis, a_W);
          for (int k = 0; k < 3; ++k) w_M[k] += a_W[k] * v[vi];
        }
        break;
      case 2:  /* prismatic: M slides along the axis */
        memcpy(X_FM.R, identity.R, sizeof X_FM.R);
        for (int k = 0; k < 3; ++k) X_FM.p[k] = axis[k] * q[qi];
        compose(&X_WF, &X_FM, &X_WM);
        if (v != NULL) {
          rotate(X_WF.R, axis, a_W);
          add_moment(v_M, w_F, X_WM.p, X_WF.p);
          for (int k = 0; k < 3; ++k) v_M[k] += a_W[k] * v[vi];
        }
        break;
      case 3:  /* quaternion floating: q = [qw, qx, qy, qz, p_FM], v = [w_FM, v_FM], both expressed in F */
        quaternion_rotation(q + qi, X_FM.R);
        memcpy(X_FM.p, q + qi + 4, sizeof X_FM.p);
        compose(&X_WF, &X_FM, &X_WM);
        if (v != NULL) {
          double w_FM_W[3], v_FM_W[3];
          rotate(X_WF.R, v + vi, w_FM_W);
          rotate(X_WF.R, v + vi + 3, v_FM_W);
          add_moment(v_M, w_F, X_WM.p, X_WF.p);
          for (int k = 0; k < 3; ++k) {
            w_M[k] += w_FM_W[k];
            v_M[k] += v_FM_W[k];
          }
        }
        break;
      default:  /* fixed */
        X_WM = X_WF;
    }
    compose(&X_WM, &X_MC, &X[i]);
    if (v != NULL) {
      memcpy(w[i], w_M, sizeof w_M);
      memcpy(vo[i], v_M, sizeof v_M);
      add_moment(vo[i], w_M, X[i].p, X_WM.p);
    }
  }
}

/* X_WF of a frame [link, X_BF]. */
static void frame_pose(const Pose *X, const double *frame, Pose *out) {
  Pose X_BF;
  read_pose(frame + 1, &X_BF);
  compose(&X[(int)frame[0]], &X_BF, out);
}

/* The model's entries of q (and with `velocities` v) from the plant's state [q, v] `object` (without
 * `velocities`, its positions q or its state), into a new array of nq (+ nv) doubles (PyMem_Free it); the
 * entries no link reads are left unset. */
static double *load_state(const Model *m, PyObject *object, int velocities) {
  Py_ssize_t n = m->nq + (velocities ? m->nv : 0);
  PyObject *sequence = PySequence_Fast(object, "_kinematics: the state must be a sequence of floats");
  if (sequence == NULL) return NULL;
  Py_ssize_t size = PySequence_Fast_GET_SIZE(sequence);
  if (size != n && !(!velocities && size == n + m->nv)) {  /* positions: q, or a whole state [q, v] */
    PyErr_Format(PyExc_ValueError, "_kinematics: the %s must have %zd entries, got %zd",
                 velocities ? "plant state [q, v]" : "positions q", n, size);
    Py_DECREF(sequence);
    return NULL;
  }
  double *x = PyMem_Malloc((n > 0 ? n : 1) * sizeof(double));
  if (x == NULL) {
    Py_DECREF(sequence);
    PyErr_NoMemory();
    return NULL;
  }
  PyObject **items = PySequence_Fast_ITEMS(sequence);
  static const int sizes[4][2] = {{0, 0}, {1, 1}, {1, 1}, {7, 6}};  /* (q, v) entries per joint type */
  for (int i = 0; i < m->n_links; ++i) {
    const double *link = m->links + i * LINK;
    int type = (int)link[1], qi = (int)link[2], vi = (int)link[3];
    for (int part = 0; part < (velocities ? 2 : 1); ++part) {
      int start = part == 0 ? qi : m->nq + vi;
      for (int k = start; k < start + sizes[type][part]; ++k) {
        x[k] = PyFloat_AsDouble(items[k]);
        if (x[k] == -1.0 && PyErr_Occurred()) {
          PyMem_Free(x);
          Py_DECREF(sequence);
          return NULL;
        }
      }
    }
  }
  Py_DECREF(sequence);
  return x;
}

/* frame_states(model, frames, x) -> [p (3), quaternion wxyz with w >= 0 (4), v_WF (3), w_WF (3)] per frame. */
static PyObject *frame_states(PyObject *self, PyObject *args) {
  PyObject *model_bytes, *frames_bytes, *state;
  if (!PyArg_ParseTuple(args, "OOO", &model_bytes, &frames_bytes, &state)) return NULL;
  Model m;
  const double *frames;
  int n_frames;
  if (read_model(model_bytes, &m) || read_frames(frames_bytes, &m, &frames, &n_frames)) return NULL;
  double *x = load_state(&m, state, 1);
  if (x == NULL) return NULL;
  Pose X[MAX_LINKS];
  double w[MAX_LINKS][3], vo[MAX_LINKS][3];
  forward(&m, x, x + m.nq, X, w, vo);
  PyMem_Free(x);
  if (n_frames > 64) {
    PyErr_SetString(PyExc_ValueError, "_kinematics: at most 64 frames per call");
    return NULL;
  }
  double out[13 * 64];
  for (int i = 0; i < n_frames; ++i) {
    const double *frame = frames + i * FRAME;
    double *row = out + 13 * i;
    int link = (int)frame[0];
    Pose X_WF;
    frame_pose(X, frame, &X_WF);
    memcpy(row, X_WF.p, 3 * sizeof(double));
    rotation_quaternion(X_WF.R, row + 3);
    memcpy(row + 7, vo[link], 3 * sizeof(double));
    add_moment(row + 7, w[link], X_WF.p, X[link].p);
    memcpy(row + 10, w[link], 3 * sizeof(double));
  }
  return list_of(out, 13 * (Py_ssize_t)n_frames);
}

/* frame_poses(model, frames, q) -> [R row-major (9), p (3)] per frame. */
static PyObject *frame_poses(PyObject *self, PyObject *args) {
  PyObject *model_bytes, *frames_bytes, *positions;
  if (!PyArg_ParseTuple(args, "OOO", &model_bytes, &frames_bytes, &positions)) return NULL;
  Model m;
  const double *frames;
  int n_frames;
  if (read_model(model_bytes, &m) || read_frames(frames_bytes, &m, &frames, &n_frames)) return NULL;
  if (n_frames > 64) {
    PyErr_SetString(PyExc_ValueError, "_kinematics: at most 64 frames per call");
    return NULL;
  }
  double *q = load_state(&m, positions, 0);
  if (q == NULL) return NULL;
  Pose X[MAX_LINKS];
  forward(&m, q, NULL, X, NULL, NULL);
  PyMem_Free(q);
  double out[12 * 64];
  for (int i = 0; i < n_frames; ++i) {
    Pose X_WF;
    frame_pose(X, frames + i * FRAME, &X_WF);
    memcpy(out + 12 * i, X_WF.R, 9 * sizeof(double));
    memcpy(out + 12 * i + 9, X_WF.p, 3 * sizeof(double));
  }
  return list_of(out, 12 * (Py_ssize_t)n_frames);
}

/* angle * axis of a rotation matrix (its log map), for every angle in [0, pi]. */
static void rotation_vector(const double *E, double *out) {
  double s[3] = {0.5 * (E[7] - E[5]), 0.5 * (E[2] - E[6]), 0.5 * (E[3] - E[1])};
  double cosine = 0.5 * (E[0] + E[4] + E[8] - 1.0);
  cosine = cosine > 1.0 ? 1.0 : (cosine < -1.0 ? -1.0 : cosine);
  double sine = sqrt(s[0] * s[0] + s[1] * s[1] + s[2] * s[2]), angle = atan2(sine, cosine);
  if (cosine > -0.5) {  /* the skew part carries the axis well: (angle / sin) s */
    double k = sine > 0.0 ? angle / sine : 1.0;
    for (int i = 0; i < 3; ++i) out[i] = k * s[i];
    return;
  }
  /* Near a half turn: (E + E^T) / 2 - cos I = (1 - cos) a a^T; the largest diagonal entry gives a stable
   * component, the others follow from its row; the skew part (sin a) fixes the sign. */
  double B[9];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j) B[3 * i + j] = (0.5 * (E[3 * i + j] + E[3 * j + i]) - (i == j ? cosine : 0.0)) /
                                              (1.0 - cosine);
  int k = B[0] >= B[4] && B[0] >= B[8] ? 0 : (B[4] >= B[8] ? 1 : 2);
  double a[3], ak = sqrt(B[4 * k] > 0.0 ? B[4 * k] : 0.0);
  for (int i = 0; i < 3; ++i) a[i] = i == k ? ak : B[3 * k + i] / ak;
  if (a[0] * s[0] + a[1] * s[1] + a[2] * s[2] < 0.0)
    for (int i = 0; i < 3; ++i) a[i] = -a[i];
  double norm = sqrt(a[0] * a[0] + a[1] * a[1] + a[2] * a[2]);
  for (int i = 0; i < 3; ++i) out[i] = angle * a[i] / norm;
}

static PyObject *rotation_vector_py(PyObject *self, PyObject *args) {
  PyObject *matrix;
  if (!PyArg_ParseTuple(args, "O", &matrix)) return NULL;
  double E[9], out[3];
  if (read_vector(matrix, 9, E, "the rotation matrix (9 entries, row by row)")) return NULL;
  rotation_vector(E, out);
  return list_of(out, 3);
}

/* dls_step(model, frame, q, p_target, R_target, orientation_weight, damping, max_step, q_min, q_max) -> q'.
 *
 * One damped least-squares step for the frame's origin C and orientation: with the error
 * e = [w log(R_target R_WC^T); p_target - p_WC] and the Jacobian J (rows: w x angular, translational),
 * dq = J^T (J J^T + damping^2 I)^-1 e, scaled down to a norm of max_step, and q + dq clamped to the limits.
 * The model's positions must all be revolute or prismatic joints (nq == nv). */
static PyObject *dls_step(PyObject *self, PyObject *args) {
  PyObject *model_bytes, *frame_bytes, *positions, *target, *target_rotation, *lower, *upper;
  double weight, damping, max_step;
  if (!PyArg_ParseTuple(args, "OOOOOdddOO", &model_bytes, &frame_bytes, &positions, &target, &target_rotation,
                        &weight, &damping, &max_step, &lower, &upper))
    return NULL;
  Model m;
  const double *frames;
  int n_frames;
  if (read_model(model_bytes, &m) || read_frames(frame_bytes, &m, &frames, &n_frames)) return NULL;
  if (n_frames != 1 || m.nq != m.nv || m.nq > MAX_DOFS) {
    PyErr_SetString(PyExc_ValueError, "_kinematics.dls_step: needs one frame and a plant whose positions "
                                         "are all revolute or prismatic joints (nq == nv <= 64)");
    return NULL;
  }
  int n = m.nq;
  double q[MAX_DOFS], q_min[MAX_DOFS], q_max[MAX_DOFS], p_T[3], R_T[9];
  if (read_vector(positions, n, q, "q") || read_vector(target, 3, p_T, "p_target") ||
      read_vector(target_rotation, 9, R_T, "R_target (9 entries, row by row)") ||
      read_vector(lower, n, q_min, "q_min") || read_vector(upper, n, q_max, "q_max"))
    return NULL;
  Pose X[MAX_LINKS], X_WC;
  forward(&m, q, NULL, X, NULL, NULL);
  frame_pose(X, frames, &X_WC);
  /* Jacobian columns: the joints on the path from C's link to the world. */
  double J[6][MAX_DOFS];
  memset(J, 0, sizeof J);
  for (int link = (int)frames[0]; link >= 0;) {
    const double *row = m.links + link * LINK;
    int parent = (int)row[0], type = (int)row[1], vi = (int)row[3];
    if (type == 3) {
      PyErr_SetString(PyExc_ValueError, "_kinematics.dls_step: a floating joint is on the chain");
      return NULL;
    }
    if (type == 1 || type == 2) {
      /* The joint frame F (= M's origin for a revolute joint) in the world. */
      Pose X_PF, X_WF;
      read_pose(row + 4, &X_PF);
      if (parent < 0) X_WF = X_PF; else compose(&X[parent], &X_PF, &X_WF);
      double a_W[3], moment[3], d[3];
      rotate(X_WF.R, row + 16, a_W);
      if (type == 1) {
        for (int k = 0; k < 3; ++k) d[k] = X_WC.p[k] - X_WF.p[k];
        cross(a_W, d, moment);
        for (int k = 0; k < 3; ++k) {
          J[k][vi] = weight * a_W[k];
          J[3 + k][vi] = moment[k];
        }
      } else {
        for (int k = 0; k < 3; ++k) J[3 + k][vi] = a_W[k];
      }
    }
    link = parent;
  }
  /* E = R_target R_WC^T: the rotation still to go. */
  double E[9], r[3], e[6];
  for (int i = 0; i < 3; ++i)
    for (int j = 0; j < 3; ++j)
      E[3 * i + j] = R_T[3 * i] * X_WC.R[3 * j] + R_T[3 * i + 1] * X_WC.R[3 * j + 1] +
                     R_T[3 * i + 2] * X_WC.R[3 * j + 2];
  rotation_vector(E, r);
  for (int k = 0; k < 3; ++k) {
    e[k] = weight * r[k];
    e[3 + k] = p_T[k] - X_WC.p[k];
  }
  /* A = J J^T + damping^2 I (symmetric positive definite): Cholesky A = L L^T, then A y = e. */
  double A[6][6], L[6][6], y[6];
  for (int i = 0; i < 6; ++i)
    for (int j = 0; j < 6; ++j) {
      double sum = i == j ? damping * damping : 0.0;
      for (int k = 0; k < n; ++k) sum += J[i][k] * J[j][k];
      A[i][j] = sum;
    }
  memset(L, 0, sizeof L);
  for (int j = 0; j < 6; ++j) {
    double d = A[j][j];
    for (int k = 0; k < j; ++k) d -= L[j][k] * L[j][k];
    if (!(d > 0.0)) {
      PyErr_SetString(PyExc_RuntimeError, "PalmIK: the damped normal matrix is not positive definite "
                                          "(damping must be non-zero and the state finite)");
      return NULL;
    }
    L[j][j] = sqrt(d);
    for (int i = j + 1; i < 6; ++i) {
      double s = A[i][j];
      for (int k = 0; k < j; ++k) s -= L[i][k] * L[j][k];
      L[i][j] = s / L[j][j];
    }
  }
  for (int i = 0; i < 6; ++i) {
    double s = e[i];
    for (int k = 0; k < i; ++k) s -= L[i][k] * y[k];
    y[i] = s / L[i][i];
  }
  for (int i = 5; i >= 0; --i) {
    double s = y[i];
    for (int k = i + 1; k < 6; ++k) s -= L[k][i] * y[k];
    y[i] = s / L[i][i];
  }
  double dq[MAX_DOFS], norm = 0.0;
  for (int k = 0; k < n; ++k) {
    dq[k] = 0.0;
    for (int i = 0; i < 6; ++i) dq[k] += J[i][k] * y[i];
    norm += dq[k] * dq[k];
  }
  norm = sqrt(norm);
  double scale = norm > max_step ? max_step / norm : 1.0;
  for (int k = 0; k < n; ++k) {
    double value = q[k] + dq[k] * scale;
    q[k] = value < q_min[k] ? q_min[k] : (value > q_max[k] ? q_max[k] : value);
  }
  return list_of(q, n);
}

static PyMethodDef methods[] = {
    {"frame_states", frame_states, METH_VARARGS,
     "frame_states(model, frames, x): per frame [p (3), quaternion wxyz, w >= 0 (4), v (3), w (3)]."},
    {"frame_poses", frame_poses, METH_VARARGS, "frame_poses(model, frames, q): per frame [R row-major (9), p (3)]."},
    {"rotation_vector", rotation_vector_py, METH_VARARGS, "rotation_vector(R9): angle * axis (the log map)."},
    {"dls_step", dls_step, METH_VARARGS,
     "dls_step(model, frame, q, p_target, R_target9, weight, damping, max_step, q_min, q_max): one DLS step."},
    {NULL, NULL, 0, NULL},
};

static struct PyModuleDef module = {PyModuleDef_HEAD_INIT, "_kinematics",
                                    "Compiled tree kinematics (see seqdex_drake.robots.tree_kinematics).", -1,
                                    methods};

PyMODINIT_FUNC PyInit__kinematics(void) { return PyModule_Create(&module); }
