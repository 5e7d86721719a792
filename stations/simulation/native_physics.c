/* The physics in C (stations/simulation/native.py loads it; without it, all runs in Python).
 *
 * The marine terms a physics step needs between MuJoCo's position and acceleration stages: the
 * hull's Fossen terms for a diagonal added mass (hydrodynamics.Fossen._apply_diagonal, the same
 * equations in the same order of operations) and the arm's added mass (strips.ArmStrips.add_mass)
 * into the inertia, then its factorisation again. MuJoCo calls abyss_marine_control as its control
 * callback (mjcb_control: after the velocity stage, where mj_step1 ends) on every step of every
 * model in the process; it acts on the MjData registered and active, and on no other. Built with
 * the compiler's floating-point contraction off, so that its arithmetic is Python's bit for bit.
 *
 * The dynamic low level, once per control period (abyss_low_level, below): alike to rounding.
 *
 * native.build compiles it (setup.sh, the image's build stage) into the environment:
 * .venv/lib/abyss/libabyss_physics.so. */
#include <math.h>
#include <string.h>

#include <mujoco/mujoco.h>

#define ABYSS_MARINE_WORLDS 1024  /* registered at once in one process */
#define ABYSS_ARM_MAX 16  /* an arm's joints at most (messages' MAX_ARM_JOINTS) */

/* the layout of the structs below, as native.py's ABI: a library built from another source is
 * refused there rather than read with the wrong layout */
int abyss_physics_abi(void) { return 2; }

typedef struct {
  const mjData* data;  /* whose steps these terms are */
  int active;          /* set around the steps it must act on */
  int body, dof;       /* the hull's body and its free joint's first dof */
  double added_mass[6], linear[6], quadratic[6];  /* diagonal M_A; D's linear and quadratic */
  double buoyancy_n, centre_of_buoyancy_m_body[3];
  int hull_entries[9]; /* the inertia's entries the hull's added mass changes */
  const double* current_mps_world;  /* 3, held by Python */
  int links;                        /* the arm's added mass: the entries' count */
  const int* link_entries;          /* held by Python */
  const double* link_values;        /* held by Python */
} AbyssMarine;

static AbyssMarine* worlds[ABYSS_MARINE_WORLDS];
static int used;  /* the slots below this may be taken: the callback looks no further */

int abyss_marine_register(AbyssMarine* terms) {
  for (int i = 0; i < ABYSS_MARINE_WORLDS; i++) {
    if (!worlds[i]) {
      worlds[i] = terms;
      if (i >= used) used = i + 1;
      return i;
    }
  }
  return -1;
}

void abyss_marine_unregister(int slot) {
  if (slot >= 0 && slot < ABYSS_MARINE_WORLDS) worlds[slot] = NULL;
}

static void hull(const AbyssMarine* w, mjData* d) {
  const mjtNum* x = d->xmat + 9 * w->body;  /* body to world, row-major */
  double r00 = x[0], r01 = x[1], r02 = x[2], r10 = x[3], r11 = x[4], r12 = x[5];
  double r20 = x[6], r21 = x[7], r22 = x[8];
  const mjtNum* v = d->qvel + w->dof;  /* free joint: linear in the world, angular in the body */
  double vx = v[0], vy = v[1], vz = v[2], p = v[3], q = v[4], r = v[5];
  const double* c = w->current_mps_world;
  double cx = c[0], cy = c[1], cz = c[2];
  double ur = r00 * vx + r10 * vy + r20 * vz - (r00 * cx + r10 * cy + r20 * cz);  /* R^T (v - v_c) */
  double vr = r01 * vx + r11 * vy + r21 * vz - (r01 * cx + r11 * cy + r21 * cz);
  double wr = r02 * vx + r12 * vy + r22 * vz - (r02 * cx + r12 * cy + r22 * cz);
  const double* m = w->added_mass;
  double a1u = m[0] * ur, a1v = m[1] * vr, a1w = m[2] * wr;
  double a2p = m[3] * p, a2q = m[4] * q, a2r = m[5] * r;
  const double *l = w->linear, *qd = w->quadratic;
  double b = w->buoyancy_n;
  double fx = b * r20, fy = b * r21, fz = b * r22;  /* R^T (0, 0, B) */
  double bx = w->centre_of_buoyancy_m_body[0], by = w->centre_of_buoyancy_m_body[1];
  double bz = w->centre_of_buoyancy_m_body[2];
  /* restoring - C_A(nu_r) nu_r - D(nu_r) nu_r + the turning part of M_A nu_r_dot */
  double t1 = fx - (q * a1w - r * a1v) - (l[0] + qd[0] * fabs(ur)) * ur + m[0] * (q * wr - r * vr);
  double t2 = fy - (r * a1u - p * a1w) - (l[1] + qd[1] * fabs(vr)) * vr + m[1] * (r * ur - p * wr);
  double t3 = fz - (p * a1v - q * a1u) - (l[2] + qd[2] * fabs(wr)) * wr + m[2] * (p * vr - q * ur);
  double t4 = (by * fz - bz * fy) - (vr * a1w - wr * a1v + q * a2r - r * a2q) - (l[3] + qd[3] * fabs(p)) * p;
  double t5 = (bz * fx - bx * fz) - (wr * a1u - ur * a1w + r * a2p - p * a2r) - (l[4] + qd[4] * fabs(q)) * q;
  double t6 = (bx * fy - by * fx) - (ur * a1v - vr * a1u + p * a2q - q * a2p) - (l[5] + qd[5] * fabs(r)) * r;
  mjtNum* f = d->qfrc_applied + w->dof;
  f[0] = r00 * t1 + r01 * t2 + r02 * t3;
  f[1] = r10 * t1 + r11 * t2 + r12 * t3;
  f[2] = r20 * t1 + r21 * t2 + r22 * t3;
  f[3] = t4;
  f[4] = t5;
  f[5] = t6;
  /* T^T M_A T: R diag(m1, m2, m3) R^T and the angular diagonal */
  const double added[9] = {
      m[0] * r00 * r00 + m[1] * r01 * r01 + m[2] * r02 * r02,
      m[0] * r10 * r00 + m[1] * r11 * r01 + m[2] * r12 * r02,
      m[0] * r10 * r10 + m[1] * r11 * r11 + m[2] * r12 * r12,
      m[0] * r20 * r00 + m[1] * r21 * r01 + m[2] * r22 * r02,
      m[0] * r20 * r10 + m[1] * r21 * r11 + m[2] * r22 * r12,
      m[0] * r20 * r20 + m[1] * r21 * r21 + m[2] * r22 * r22,
      m[3],
      m[4],
      m[5],
  };
  for (int i = 0; i < 9; i++) d->M[w->hull_entries[i]] += added[i];
}

void abyss_marine_control(const mjModel* m, mjData* d) {
  for (int i = 0; i < used; i++) {
    const AbyssMarine* w = worlds[i];
    if (!w || w->data != d || !w->active) continue;
    hull(w, d);
    for (int k = 0; k < w->links; k++) d->M[w->link_entries[k]] += w->link_values[k];
    mj_factorM(m, d);
    return;
  }
}

/* ---- the dynamic low level, once per control period (lowlevel.Dynamic.apply with
 * thrusters.Thrusters, then strips.ArmStrips.apply): the same equations as the Python, summed in
 * C's order rather than numpy's BLAS's, so alike to rounding, not bit for bit. */

typedef struct {
  /* the vehicle's velocity controller: PID on the actuated axes (surge, sway, heave, yaw) with a
   * feed-forward of the damping at the reference */
  int qpos, qvel;                       /* the free joint's addresses */
  double kp[4], ki[4], kd[4], linear[4], quadratic[4];
  double* integral;                     /* 4, held by Python */
  double* error;                        /* 4, the last period's, held by Python */
  /* its thrusters: allocation by pseudo-inverse, scaled into their limits, rotors as a lag; the
   * wrench's rows: the four axes, then the attitude hold's (attitude.py), roll's and pitch's */
  int thrusters, rows;
  const int* actuators;                 /* per thruster */
  const double* pinv;                   /* thrusters x rows, row-major */
  const double* allocation;             /* rows x thrusters, row-major */
  /* the attitude hold: a PD towards level on the held axes (0 roll, 1 pitch), rows - 4 of them */
  int held[2];
  double attitude_kp[2], attitude_kd[2];
  double forward_max_n, reverse_max_n, deadband, time_constant_s;
  const double* efficiency;             /* per thruster, held by Python (faults) */
  double* rotor_speed;                  /* per thruster, held by Python */
  /* the arm's velocity servos (MuJoCo's, kv = arm_kp) with an integral on their set points */
  int arm_joints, arm_dofs[ABYSS_ARM_MAX], arm_motors[ABYSS_ARM_MAX], grippers, gripper_motors[2];
  double arm_kp, arm_ki, arm_force_limit[ABYSS_ARM_MAX];
  double* arm_integral;                 /* per arm joint, held by Python */
  /* the references [m/s, rad/s] and the period [s]: vehicle 4, gripper, period, then the arm's */
  const double* references;             /* 6 + arm joints, held by Python */
  const double* current_mps_world;      /* 3, held by Python */
  /* the links' strip model */
  int links, strips, dofs, root, added_inertia, entries;
  const int* bodies;                    /* per link */
  const int* owner;                     /* per strip: its link */
  const int* dof;                       /* the dofs that move a link */
  const int* flat;                      /* per inertia entry: its index in the dofs x dofs matrix */
  const double* q;                      /* per strip, 3 x 6: Q_k */
  const double* drag;                   /* per strip, 3 */
  const double* kirchhoff;              /* per link, 6 x 36 */
  const double* buoyancy;               /* per link, 6 x 3 */
  const double* added_mass;             /* per link, 6 x 6 */
  const double* mask;                   /* per link, dofs */
  double* jacobian;                     /* per link, 6 x dofs: scratch, held by Python */
  double* mass_q;                       /* dofs x dofs: scratch, held by Python */
  double* values;                       /* per inertia entry, held by Python */
} AbyssLowLevel;

static double sign(double x) { return (x > 0.0) - (x < 0.0); }

static double max_thrust(const AbyssLowLevel* c, double thrust_n) {
  return thrust_n >= 0.0 ? c->forward_max_n : c->reverse_max_n;
}

static void vehicle(AbyssLowLevel* c, mjData* d) {
  const double* ref = c->references;
  double dt = c->references[5];
  double rotation[9];
  mju_quat2Mat(rotation, d->qpos + c->qpos + 3);
  const mjtNum* v = d->qvel + c->qvel;  /* linear in the world, angular in the body */
  double velocity[4] = {
      rotation[0] * v[0] + rotation[3] * v[1] + rotation[6] * v[2],
      rotation[1] * v[0] + rotation[4] * v[1] + rotation[7] * v[2],
      rotation[2] * v[0] + rotation[5] * v[1] + rotation[8] * v[2],
      v[5],
  };
  double wrench[6], candidate[4];
  for (int i = 0; i < 4; i++) {
    double error = ref[i] - velocity[i];
    double derivative = (error - c->error[i]) / dt;
    c->error[i] = error;
    double feed_forward = (c->linear[i] + c->quadratic[i] * fabs(ref[i])) * ref[i];
    candidate[i] = c->integral[i] + error * dt;
    wrench[i] = feed_forward + c->kp[i] * error + c->kd[i] * derivative + c->ki[i] * candidate[i];
  }
  if (c->rows > 4) {  /* the attitude hold's moments: towards level, damped */
    double angles[2] = {atan2(rotation[7], rotation[8]), -asin(fmin(fmax(rotation[6], -1.0), 1.0))};
    for (int h = 0; h < c->rows - 4; h++) {
      int axis = c->held[h];
      wrench[4 + h] = -c->attitude_kp[h] * angles[axis] - c->attitude_kd[h] * v[3 + axis];
    }
  }
  int n = c->thrusters, rows = c->rows;
  double thrust[64], excess = 0.0;
  for (int k = 0; k < n; k++) {
    const double* row = c->pinv + rows * k;
    thrust[k] = 0.0;
    for (int i = 0; i < rows; i++) thrust[k] += row[i] * wrench[i];
    double share = fabs(thrust[k]) / max_thrust(c, thrust[k]);
    if (share > excess) excess = share;
  }
  if (excess > 1.0) for (int k = 0; k < n; k++) thrust[k] /= excess;
  int saturated = 0;  /* anti-windup: integrate only when the thrusters deliver the wrench */
  for (int i = 0; i < rows; i++) {
    double delivered = 0.0;
    for (int k = 0; k < n; k++) delivered += c->allocation[n * i + k] * thrust[k];
    if (!(fabs(delivered - wrench[i]) <= 1e-6 + 1e-6 * fabs(wrench[i]))) saturated = 1;
  }
  if (!saturated) for (int i = 0; i < 4; i++) c->integral[i] = candidate[i];
  double db = c->deadband, decay = exp(-dt / c->time_constant_s);
  for (int k = 0; k < n; k++) {
    /* the command that delivers the thrust at steady state, then the rotor's lag towards it */
    double speed = sqrt(fmin(fabs(thrust[k]) / max_thrust(c, thrust[k]), 1.0));
    double command = speed > 0.0 ? sign(thrust[k]) * (db + (1.0 - db) * speed) : 0.0;
    command = fmin(fmax(command, -1.0), 1.0);
    double target = sign(command) * fmax(fabs(command) - db, 0.0) / (1.0 - db);
    double rotor = target + (c->rotor_speed[k] - target) * decay;
    c->rotor_speed[k] = rotor;
    d->ctrl[c->actuators[k]] = max_thrust(c, rotor) * rotor * fabs(rotor) * c->efficiency[k];
  }
}

static void arm(AbyssLowLevel* c, mjData* d) {
  const double* ref = c->references + 6;
  double dt = c->references[5], candidate[ABYSS_ARM_MAX];
  int within = 1, joints = c->arm_joints;
  for (int j = 0; j < joints; j++) {
    double error = ref[j] - d->qvel[c->arm_dofs[j]];
    candidate[j] = c->arm_integral[j] + error * dt;
    if (!(fabs(c->arm_kp * error + c->arm_ki * candidate[j]) < c->arm_force_limit[j])) within = 0;
  }
  if (within) for (int j = 0; j < joints; j++) c->arm_integral[j] = candidate[j];
  for (int j = 0; j < joints; j++) d->ctrl[c->arm_motors[j]] = ref[j] + c->arm_ki / c->arm_kp * c->arm_integral[j];
  for (int j = 0; j < c->grippers; j++) d->ctrl[c->gripper_motors[j]] = c->references[4];
}

/* each link's twist relative to the water (body frame, about its centre of mass), its wrench into
 * xfrc_applied, its Jacobian; then the added mass in joint space */
static void links(AbyssLowLevel* c, mjData* d) {
  const double* water = c->current_mps_world;
  const double* com = d->subtree_com + 3 * c->root;
  int nd = c->dofs, strip = 0;
  double* j = c->jacobian;
  for (int i = 0; i < c->links; i++) {
    int b = c->bodies[i];
    const double* r = d->xmat + 9 * b;  /* body to world, row-major */
    double lever[3] = {d->xipos[3 * b] - com[0], d->xipos[3 * b + 1] - com[1], d->xipos[3 * b + 2] - com[2]};
    /* X = [[R^T (-[lever]x), R^T], [R^T, 0]] on cvel's (omega, v) */
    double x[36] = {0};
    for (int row = 0; row < 3; row++) {
      double r0 = r[row], r1 = r[3 + row], r2 = r[6 + row];  /* R^T's row */
      x[6 * row + 0] = r2 * lever[1] - r1 * lever[2];
      x[6 * row + 1] = r0 * lever[2] - r2 * lever[0];
      x[6 * row + 2] = r1 * lever[0] - r0 * lever[1];
      x[6 * row + 3] = r0, x[6 * row + 4] = r1, x[6 * row + 5] = r2;
      x[6 * (row + 3) + 0] = r0, x[6 * (row + 3) + 1] = r1, x[6 * (row + 3) + 2] = r2;
    }
    const double* cvel = d->cvel + 6 * b;
    double relative[6] = {cvel[0], cvel[1], cvel[2], cvel[3] - water[0], cvel[4] - water[1], cvel[5] - water[2]};
    double nu[6];
    for (int row = 0; row < 6; row++) {
      nu[row] = 0.0;
      for (int k = 0; k < 6; k++) nu[row] += x[6 * row + k] * relative[k];
    }
    /* the strips' drag: -sum_k Q_k^T (c_k |u| u) */
    double wrench[6] = {0};
    for (; strip < c->strips && c->owner[strip] == i; strip++) {
      const double* q = c->q + 18 * strip;
      double u[3];
      for (int a = 0; a < 3; a++) {
        u[a] = 0.0;
        for (int k = 0; k < 6; k++) u[a] += q[6 * a + k] * nu[k];
      }
      double across = sqrt(u[0] * u[0] + u[1] * u[1]), along = fabs(u[2]);
      const double* drag = c->drag + 3 * strip;
      double f[3] = {drag[0] * across * u[0], drag[1] * across * u[1], drag[2] * along * u[2]};
      for (int k = 0; k < 6; k++) wrench[k] -= q[k] * f[0] + q[6 + k] * f[1] + q[12 + k] * f[2];
    }
    /* the added mass's velocity terms (Kirchhoff) and the buoyancy */
    const double* kirchhoff = c->kirchhoff + 216 * i;
    const double* buoyancy = c->buoyancy + 18 * i;
    for (int row = 0; row < 6; row++) {
      double sum = 0.0;
      for (int a = 0; a < 6; a++)
        for (int k = 0; k < 6; k++) sum += kirchhoff[36 * row + 6 * a + k] * nu[a] * nu[k];
      wrench[row] += sum + buoyancy[3 * row] * r[6] + buoyancy[3 * row + 1] * r[7] + buoyancy[3 * row + 2] * r[8];
    }
    mjtNum* out = d->xfrc_applied + 6 * b;  /* world frame: R f, R m */
    for (int row = 0; row < 3; row++) {
      out[row] = r[3 * row] * wrench[0] + r[3 * row + 1] * wrench[1] + r[3 * row + 2] * wrench[2];
      out[3 + row] = r[3 * row] * wrench[3] + r[3 * row + 1] * wrench[4] + r[3 * row + 2] * wrench[5];
    }
    /* J_b = X cdof^T, on the dofs that move the link */
    double* jb = j + 6 * nd * i;
    for (int a = 0; a < nd; a++) {
      const double* cdof = d->cdof + 6 * c->dof[a];
      double on = c->mask[nd * i + a];
      for (int row = 0; row < 6; row++) {
        double sum = 0.0;
        for (int k = 0; k < 6; k++) sum += x[6 * row + k] * cdof[k];
        jb[nd * row + a] = sum * on;
      }
    }
  }
  if (!c->added_inertia) return;
  /* sum_b J_b^T M_A,b J_b */
  double* mq = c->mass_q;
  memset(mq, 0, sizeof(double) * nd * nd);
  double mj[6 * 64];
  for (int i = 0; i < c->links; i++) {
    const double* jb = j + 6 * nd * i;
    const double* ma = c->added_mass + 36 * i;
    for (int row = 0; row < 6; row++)
      for (int a = 0; a < nd; a++) {
        double sum = 0.0;
        for (int k = 0; k < 6; k++) sum += ma[6 * row + k] * jb[nd * k + a];
        mj[nd * row + a] = sum;
      }
    for (int a = 0; a < nd; a++)
      for (int e = 0; e < nd; e++) {
        double sum = 0.0;
        for (int k = 0; k < 6; k++) sum += jb[nd * k + a] * mj[nd * k + e];
        mq[nd * a + e] += sum;
      }
  }
  for (int k = 0; k < c->entries; k++) c->values[k] = mq[c->flat[k]];
}

/* One control period's low level: the controllers, then the links' marine forces from the
 * current kinematics. */
void abyss_low_level(AbyssLowLevel* c, mjData* d) {
  vehicle(c, d);
  arm(c, d);
  links(c, d);
}
