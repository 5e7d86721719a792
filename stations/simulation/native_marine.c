/* The marine terms a physics step needs between MuJoCo's position and acceleration stages, in C:
 * the hull's Fossen terms for a diagonal added mass (hydrodynamics.Fossen._apply_diagonal, the
 * same equations in the same order of operations) and the arm's added mass (links.Links.add_mass)
 * into the inertia, then its factorisation again. MuJoCo calls abyss_marine_control as its control
 * callback (mjcb_control: after the velocity stage, where mj_step1 ends) on every step of every
 * model in the process; it acts on the MjData registered and active, and on no other. Built by
 * setup.sh with the compiler's floating-point contraction off, so that its arithmetic is Python's
 * bit for bit, into .venv/lib/abyss/libabyss_marine.so (stations/simulation/native.py loads it;
 * without it, the steps run in Python). */
#include <math.h>
#include <string.h>

#include <mujoco/mujoco.h>

#define ABYSS_MARINE_WORLDS 1024  /* registered at once in one process */

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
