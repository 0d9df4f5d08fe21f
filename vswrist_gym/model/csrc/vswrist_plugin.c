/* The VS-Wrist's springs and motor setpoint dynamics as MuJoCo engine plugins.

   vswrist.drive (passive force + actuator capability), one instance per motor. The bodies that reference the
   instance (<body><plugin instance="..."/></body>) each carry exactly one hinge or slide joint:
   - two bodies and config K, delta0: a series sinh spring between their joints, tau = -2 K sinh(delta/delta0),
     delta = q(second body) - q(first body) in body order; +tau on the second joint, -tau on the first (the law
     is odd, so the order changes no force);
   - config time_constant, speed_limit, lead: the setpoint dynamics of every actuator with dyntype="user" on
     one of those joints, d act/dt = clip((ctrl - act) / time_constant, +-speed_limit), kept within +-lead
     of the joint angle (the actuator's own gain/bias make the PD loop from act).
   vswrist.closure (passive force capability, no force): one body references it; the largest violation of
   the welds between that body and others (origin distance in m or frame angle in rad, whichever is larger)
   seen at any evaluation of the passive forces is kept in the instance's plugin state.
   vswrist.contact (passive force capability, no force): one body references it; config geom1 (a geom name)
   and optionally geom2 select contacts (geom1 with geom2 in either order, or geom1 with anything). After the
   constraint solve of every substep (the advance callback, which runs after the integration: the contact
   list, the solved forces efc_force and the body velocities are still those of the state the substep started
   from) it adds the selected contacts' normal forces (mj_contactForce) and counts the substep; at the first
   substep with a selected contact it keeps that substep's time (after it), the first such contact's position
   and the referencing body's linear velocity (mj_objectVelocity, world frame). The owner reads and clears
   the state between windows; mj_resetData leaves it (MuJoCo's automatic reset inside a diverging mj_step
   must not erase what the window measured before), init zeroes it.

   All mutable state lives in the mjData (plugin_data: the resolved addresses; plugin_state: the closure
   peak); nothing is global, so separate mjData can step on separate threads. Configuration errors are
   reported by the model compiler, naming the instance: in nstate, and for the actuators and welds
   (not in the model yet when the compiler asks for nstate) in init, which runs whenever an mjData is made,
   the compiler's own included. */
/* Constants shared with Python: vswrist_gym.model.plugin_lib passes them as -D flags (one definition, in Python). */
#ifndef VSWRIST_DRIVE_NAME
#error "VSWRIST_DRIVE_NAME (the drive plugin's name, a string) is not defined: compile this file through vswrist_gym.model.plugin_lib"
#endif
#ifndef VSWRIST_CLOSURE_NAME
#error "VSWRIST_CLOSURE_NAME (the closure plugin's name, a string) is not defined: compile this file through vswrist_gym.model.plugin_lib"
#endif
#ifndef VSWRIST_CONTACT_NAME
#error "VSWRIST_CONTACT_NAME (the contact plugin's name, a string) is not defined: compile this file through vswrist_gym.model.plugin_lib"
#endif
#ifndef VSWRIST_CONTACT_NSTATE
#error "VSWRIST_CONTACT_NSTATE (numbers of a contact instance's plugin state) is not defined: compile this file through vswrist_gym.model.plugin_lib"
#endif
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <mujoco/mujoco.h>

#define VSWRIST_MAX_SERVO 8
#define VSWRIST_ERR 400

typedef struct {
  int nbody, body[2], dof[2], qadr[2];
  int spring;
  mjtNum twoK, inv_d0;
  int nservo, servo[VSWRIST_MAX_SERVO];
  mjtNum tc, vmax, lead;
} Drive;

static const char* drive_attributes[] = {"K", "delta0", "time_constant", "speed_limit", "lead"};

static const char* instance_name(const mjModel* m, int instance) {
  return m->names + m->name_pluginadr[instance];
}

/* 1: a finite number was given; 0: key absent; -1: not a number */
static int config_number(const mjModel* m, int instance, const char* key, mjtNum* out) {
  const char* s = mj_getPluginConfig(m, instance, key);
  if (!s || !s[0]) return 0;
  char* end = 0;
  const double v = strtod(s, &end);
  while (end && (*end == ' ' || *end == '\t' || *end == '\n')) end++;
  if (end == s || (end && *end) || !isfinite(v)) return -1;
  *out = v;
  return 1;
}

/* with_actuators = 0 in the compiler, where the actuators are not in the model yet */
static int drive_resolve(const mjModel* m, int instance, Drive* s, char* err, int with_actuators) {
  const char* name = instance_name(m, instance);
  memset(s, 0, sizeof(*s));
  for (int b = 0; b < m->nbody; b++) {
    if (m->body_plugin[b] != instance) continue;
    if (s->nbody == 2) {
      snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': more than two bodies reference it", name);
      return 0;
    }
    const int j = m->body_jntadr[b];
    if (m->body_jntnum[b] != 1 || (m->jnt_type[j] != mjJNT_HINGE && m->jnt_type[j] != mjJNT_SLIDE)) {
      snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': body '%s' must have exactly one hinge or slide "
               "joint", name, m->names + m->name_bodyadr[b]);
      return 0;
    }
    s->body[s->nbody] = b;
    s->dof[s->nbody] = m->jnt_dofadr[j];
    s->qadr[s->nbody] = m->jnt_qposadr[j];
    s->nbody++;
  }
  if (s->nbody == 0) {
    snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': no body references it (add <plugin instance=\"%s\"/> "
             "to the motor's body, and to the body on the spring's other side)", name, name);
    return 0;
  }
  mjtNum K = 0, d0 = 0;
  const int hk = config_number(m, instance, "K", &K), hd = config_number(m, instance, "delta0", &d0);
  if (hk < 0 || hd < 0 || hk != hd || (hk && !(K > 0 && d0 > 0))) {
    snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': config K (N m) and delta0 (rad) must both be positive "
             "numbers, or both be left out (a motor without spring)", name);
    return 0;
  }
  if (hk) {
    if (s->nbody != 2) {
      snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': a spring (K, delta0) needs two bodies referencing "
               "the instance, got %d", name, s->nbody);
      return 0;
    }
    s->spring = 1;
    s->twoK = 2.0 * K;
    s->inv_d0 = 1.0 / d0;
  }
  for (int a = 0; with_actuators && a < m->nu; a++) {
    if (m->actuator_trntype[a] != mjTRN_JOINT || m->actuator_dyntype[a] != mjDYN_USER) continue;
    const int j = m->actuator_trnid[2 * a];
    for (int k = 0; k < s->nbody; k++) {
      if (m->body_jntadr[s->body[k]] != j) continue;
      if (m->actuator_actnum[a] != 1 || s->nservo == VSWRIST_MAX_SERVO) {
        snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': actuator '%s' needs exactly one activation "
                 "(and at most %d actuators per instance)", name, m->names + m->name_actuatoradr[a],
                 VSWRIST_MAX_SERVO);
        return 0;
      }
      s->servo[s->nservo++] = a;
    }
  }
  const int ht = config_number(m, instance, "time_constant", &s->tc);
  const int hv = config_number(m, instance, "speed_limit", &s->vmax);
  const int hl = config_number(m, instance, "lead", &s->lead);
  if (ht < 0 || hv < 0 || hl < 0 || ht != hv || hv != hl || (ht && !(s->tc > 0 && s->vmax > 0 && s->lead > 0))) {
    snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': config time_constant (s), speed_limit (rad/s) and lead "
             "(rad) must all be positive numbers, or all be left out", name);
    return 0;
  }
  if (with_actuators && ht && !s->nservo) {
    snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': motor constants given but no actuator with "
             "dyntype=\"user\" acts on the joints of the bodies that reference it", name);
    return 0;
  }
  if (with_actuators && !ht && s->nservo) {
    snprintf(err, VSWRIST_ERR, "vswrist.drive instance '%s': actuator '%s' has dyntype=\"user\" on its joint but the "
             "instance has no time_constant, speed_limit, lead", name, m->names + m->name_actuatoradr[s->servo[0]]);
    return 0;
  }
  return 1;
}

/* runs in the model compiler: configuration errors become compiler errors naming the instance */
static int drive_nstate(const mjModel* m, int instance) {
  Drive s;
  char err[VSWRIST_ERR];
  if (!drive_resolve(m, instance, &s, err, 0)) mju_error("%s", err);
  return 0;
}

static int drive_init(const mjModel* m, mjData* d, int instance) {
  Drive* s = (Drive*)malloc(sizeof(Drive));
  char err[VSWRIST_ERR];
  if (!s) return -1;
  if (!drive_resolve(m, instance, s, err, 1)) {
    free(s);
    mju_error("%s", err);  /* mj_makeData's own message would not say what is wrong */
  }
  d->plugin_data[instance] = (uintptr_t)s;
  return 0;
}

static void drive_destroy(mjData* d, int instance) {
  free((void*)d->plugin_data[instance]);
  d->plugin_data[instance] = 0;
}

static void drive_copy(mjData* dest, const mjModel* m, const mjData* src, int instance) {
  const Drive* from = (const Drive*)src->plugin_data[instance];
  Drive* to = (Drive*)dest->plugin_data[instance];
  if (!from || to == from) return;
  if (!to) {
    to = (Drive*)malloc(sizeof(Drive));
    if (!to) mju_error("vswrist.drive: out of memory copying mjData");
    dest->plugin_data[instance] = (uintptr_t)to;
  }
  memcpy(to, from, sizeof(Drive));
}

static void drive_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data, int instance) {}

/* the spring: tau = -2 K sinh((q_b - q_a) / delta0), +tau on joint b, -tau on joint a */
static void drive_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  if (!(capability_bit & mjPLUGIN_PASSIVE)) return;  /* actuator forces: the actuators' own gain and bias */
  const Drive* s = (const Drive*)d->plugin_data[instance];
  if (!s || !s->spring) return;
  const mjtNum delta = d->qpos[s->qadr[1]] - d->qpos[s->qadr[0]];
  const mjtNum tau = -s->twoK * sinh(delta * s->inv_d0);
  d->qfrc_passive[s->dof[1]] += tau;
  d->qfrc_passive[s->dof[0]] -= tau;
}

/* Servo setpoint: a rate-limited first-order low-pass of the reference (ctrl), kept within +-lead of the
   joint angle q (following-error limit, lead = kd vmax / kp): the PD loop kp (act - q) - kd qdot then never
   asks for more than vmax and does not wind up when the torque saturates. */
static void drive_act_dot(const mjModel* m, mjData* d, int instance) {
  const Drive* s = (const Drive*)d->plugin_data[instance];
  if (!s) return;
  const mjtNum tb = 2.0 * m->opt.timestep;
  for (int k = 0; k < s->nservo; k++) {
    const int id = s->servo[k];
    const int adr = m->actuator_actadr[id];
    const mjtNum act = d->act[adr];
    const int jnt = m->actuator_trnid[2 * id];
    const mjtNum q = d->qpos[m->jnt_qposadr[jnt]], qdot = d->qvel[m->jnt_dofadr[jnt]];
    mjtNum rate = (d->ctrl[m->actuator_ctrladr[id]] - act) / s->tc;
    if (rate > s->vmax) rate = s->vmax;
    if (rate < -s->vmax) rate = -s->vmax;
    const mjtNum hi = qdot + (q + s->lead - act) / tb, lo = qdot + (q - s->lead - act) / tb;
    if (rate > hi) rate = hi;
    if (rate < lo) rate = lo;
    d->act_dot[adr] = rate;
  }
}

/* ------------------------------------------------------------------------------- vswrist.closure */
#define VSWRIST_MAX_WELDS 16

typedef struct {
  int body, nend, end[VSWRIST_MAX_WELDS];  /* the referencing body and the bodies welded to it */
} Closure;

static int closure_body(const mjModel* m, int instance) {
  for (int b = 0; b < m->nbody; b++) {
    if (m->body_plugin[b] == instance) return b;
  }
  return -1;
}

static int closure_nstate(const mjModel* m, int instance) {
  int n = 0;
  for (int b = 0; b < m->nbody; b++) n += m->body_plugin[b] == instance;
  if (n != 1) {
    mju_error("vswrist.closure instance '%s': exactly one body must reference it, got %d",
              instance_name(m, instance), n);
  }
  return 1;
}

/* the equality constraints are not in the model yet when the compiler asks for nstate */
static int closure_init(const mjModel* m, mjData* d, int instance) {
  Closure* s = (Closure*)malloc(sizeof(Closure));
  if (!s) return -1;
  s->body = closure_body(m, instance);
  s->nend = 0;
  for (int e = 0; s->body >= 0 && e < m->neq; e++) {
    if (m->eq_type[e] != mjEQ_WELD || m->eq_objtype[e] != mjOBJ_BODY) continue;
    const int other = m->eq_obj1id[e] == s->body ? m->eq_obj2id[e] :
                      (m->eq_obj2id[e] == s->body ? m->eq_obj1id[e] : -1);
    if (other < 0) continue;
    if (s->nend == VSWRIST_MAX_WELDS) {
      free(s);
      mju_error("vswrist.closure instance '%s': more than %d welds on its body", instance_name(m, instance),
                VSWRIST_MAX_WELDS);
    }
    s->end[s->nend++] = other;
  }
  if (!s->nend) {
    free(s);
    mju_error("vswrist.closure instance '%s': no weld joins the body that references it to another body",
              instance_name(m, instance));
  }
  d->plugin_data[instance] = (uintptr_t)s;
  return 0;
}

static void closure_destroy(mjData* d, int instance) {
  free((void*)d->plugin_data[instance]);
  d->plugin_data[instance] = 0;
}

static void closure_copy(mjData* dest, const mjModel* m, const mjData* src, int instance) {
  const Closure* from = (const Closure*)src->plugin_data[instance];
  Closure* to = (Closure*)dest->plugin_data[instance];
  if (!from || to == from) return;
  if (!to) {
    to = (Closure*)malloc(sizeof(Closure));
    if (!to) mju_error("vswrist.closure: out of memory copying mjData");
    dest->plugin_data[instance] = (uintptr_t)to;
  }
  memcpy(to, from, sizeof(Closure));
}

static void closure_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data, int instance) {
  plugin_state[0] = 0;
}

/* Body poses are current here (mj_fwdPosition runs before mj_passive), so a step of n substeps checks the
   state at the start of each of them, for a few dozen flops each. */
static void closure_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {
  if (!(capability_bit & mjPLUGIN_PASSIVE)) return;
  const Closure* s = (const Closure*)d->plugin_data[instance];
  if (!s) return;
  mjtNum* peak = d->plugin_state + m->plugin_stateadr[instance];
  const mjtNum* pc = d->xpos + 3 * s->body;
  const mjtNum* qc = d->xquat + 4 * s->body;
  mjtNum worst = peak[0];
  for (int k = 0; k < s->nend; k++) {
    const int e = s->end[k];
    const mjtNum* pe = d->xpos + 3 * e;
    const mjtNum* qe = d->xquat + 4 * e;
    const mjtNum dx = pe[0] - pc[0], dy = pe[1] - pc[1], dz = pe[2] - pc[2];
    const mjtNum dist = sqrt(dx * dx + dy * dy + dz * dz);
    mjtNum dot = fabs(qc[0] * qe[0] + qc[1] * qe[1] + qc[2] * qe[2] + qc[3] * qe[3]);
    if (dot > 1.0) dot = 1.0;
    const mjtNum angle = 2.0 * acos(dot);
    if (dist > worst) worst = dist;
    if (angle > worst) worst = angle;
  }
  peak[0] = worst;
}

/* ------------------------------------------------------------------------------- vswrist.contact */

typedef struct {
  int body, geom1, geom2;  /* geom2 -1: geom1 against anything */
} ContactMeter;

static int contact_nstate(const mjModel* m, int instance) {
  int n = 0;
  for (int b = 0; b < m->nbody; b++) n += m->body_plugin[b] == instance;
  if (n != 1) {
    mju_error("vswrist.contact instance '%s': exactly one body must reference it, got %d",
              instance_name(m, instance), n);
  }
  return VSWRIST_CONTACT_NSTATE;
}

/* -2: key absent; -1: not a geom of the model */
static int config_geom(const mjModel* m, int instance, const char* key) {
  const char* s = mj_getPluginConfig(m, instance, key);
  if (!s || !s[0]) return -2;
  return mj_name2id(m, mjOBJ_GEOM, s);
}

/* the geoms are resolved here: the compiler asks for nstate before they are all in the model */
static int contact_init(const mjModel* m, mjData* d, int instance) {
  const char* name = instance_name(m, instance);
  ContactMeter* s = (ContactMeter*)malloc(sizeof(ContactMeter));
  if (!s) return -1;
  s->body = closure_body(m, instance);
  s->geom1 = config_geom(m, instance, "geom1");
  s->geom2 = config_geom(m, instance, "geom2");
  if (s->geom1 < 0 || s->geom2 == -1) {
    const char* g1 = mj_getPluginConfig(m, instance, "geom1");
    const char* g2 = mj_getPluginConfig(m, instance, "geom2");
    free(s);
    mju_error("vswrist.contact instance '%s': config geom1 must name a geom of the model and geom2 another "
              "one or be left out, got geom1 '%s', geom2 '%s'", name, g1 ? g1 : "", g2 ? g2 : "");
  }
  if (s->geom2 == -2) s->geom2 = -1;
  d->plugin_data[instance] = (uintptr_t)s;
  memset(d->plugin_state + m->plugin_stateadr[instance], 0, VSWRIST_CONTACT_NSTATE * sizeof(mjtNum));
  return 0;
}

static void contact_destroy(mjData* d, int instance) {
  free((void*)d->plugin_data[instance]);
  d->plugin_data[instance] = 0;
}

static void contact_copy(mjData* dest, const mjModel* m, const mjData* src, int instance) {
  const ContactMeter* from = (const ContactMeter*)src->plugin_data[instance];
  ContactMeter* to = (ContactMeter*)dest->plugin_data[instance];
  if (!from || to == from) return;
  if (!to) {
    to = (ContactMeter*)malloc(sizeof(ContactMeter));
    if (!to) mju_error("vswrist.contact: out of memory copying mjData");
    dest->plugin_data[instance] = (uintptr_t)to;
  }
  memcpy(to, from, sizeof(ContactMeter));
}

static void contact_reset(const mjModel* m, mjtNum* plugin_state, void* plugin_data, int instance) {}

static void contact_compute(const mjModel* m, mjData* d, int instance, int capability_bit) {}

/* after the substep's integration (mj_advance): d->contact, efc_force, cvel, xpos are still the substep's own */
static void contact_advance(const mjModel* m, mjData* d, int instance) {
  const ContactMeter* s = (const ContactMeter*)d->plugin_data[instance];
  if (!s) return;
  mjtNum* st = d->plugin_state + m->plugin_stateadr[instance];
  mjtNum f[6], v[6];
  for (int i = 0; i < d->ncon; i++) {
    const mjContact* c = d->contact + i;
    const int g1 = c->geom[0], g2 = c->geom[1];
    const int hit = s->geom2 < 0 ? (g1 == s->geom1 || g2 == s->geom1) :
                    ((g1 == s->geom1 && g2 == s->geom2) || (g1 == s->geom2 && g2 == s->geom1));
    if (!hit) continue;
    if (st[2] == 0) {
      mj_objectVelocity(m, d, mjOBJ_BODY, s->body, v, 0);
      st[2] = 1;
      st[3] = d->time;
      st[4] = c->pos[0];
      st[5] = c->pos[1];
      st[6] = c->pos[2];
      st[7] = v[3];
      st[8] = v[4];
      st[9] = v[5];
    }
    mj_contactForce(m, d, i, f);
    st[0] += f[0];
  }
  st[1] += 1;
}

mjPLUGIN_LIB_INIT(vswrist_plugins) {
  mjpPlugin drive;
  mjp_defaultPlugin(&drive);
  drive.name = VSWRIST_DRIVE_NAME;
  drive.capabilityflags = mjPLUGIN_PASSIVE | mjPLUGIN_ACTUATOR;
  drive.nattribute = sizeof(drive_attributes) / sizeof(drive_attributes[0]);
  drive.attributes = drive_attributes;
  drive.nstate = drive_nstate;
  drive.init = drive_init;
  drive.destroy = drive_destroy;
  drive.copy = drive_copy;
  drive.reset = drive_reset;
  drive.compute = drive_compute;
  drive.actuator_act_dot = drive_act_dot;
  mjp_registerPlugin(&drive);

  mjpPlugin closure;
  mjp_defaultPlugin(&closure);
  closure.name = VSWRIST_CLOSURE_NAME;
  closure.capabilityflags = mjPLUGIN_PASSIVE;
  closure.nattribute = 0;
  closure.attributes = 0;
  closure.nstate = closure_nstate;
  closure.init = closure_init;
  closure.destroy = closure_destroy;
  closure.copy = closure_copy;
  closure.reset = closure_reset;
  closure.compute = closure_compute;
  mjp_registerPlugin(&closure);

  static const char* contact_attributes[] = {"geom1", "geom2"};
  mjpPlugin contact;
  mjp_defaultPlugin(&contact);
  contact.name = VSWRIST_CONTACT_NAME;
  contact.capabilityflags = mjPLUGIN_PASSIVE;  /* a body may reference only passive-force plugins */
  contact.nattribute = 2;
  contact.attributes = contact_attributes;
  contact.nstate = contact_nstate;
  contact.init = contact_init;
  contact.destroy = contact_destroy;
  contact.copy = contact_copy;
  contact.reset = contact_reset;
  contact.compute = contact_compute;
  contact.advance = contact_advance;
  mjp_registerPlugin(&contact);
}
