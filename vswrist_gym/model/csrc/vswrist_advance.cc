/* One control period of many worlds in one call, with a thread pool: the compiled advance of
   vswrist_gym.model.advance_lib (its docstring says why and what it does per world). */
/* Constants shared with Python: vswrist_gym.model.advance_lib passes them as -D flags (one definition, in Python). */
#ifndef VSWRIST_HANDLE_COLUMNS
#error "VSWRIST_HANDLE_COLUMNS (columns of the handle table) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_H_MODEL
#error "VSWRIST_H_MODEL (handle column) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_H_DATA
#error "VSWRIST_H_DATA (handle column) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_H_PEAK
#error "VSWRIST_H_PEAK (handle column) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_H_METER
#error "VSWRIST_H_METER (handle column) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_H_LATENCY
#error "VSWRIST_H_LATENCY (handle column) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_H_WATCH
#error "VSWRIST_H_WATCH (handle column) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_WATCH_SIZE
#error "VSWRIST_WATCH_SIZE (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_C
#error "VSWRIST_W_C (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_DIR
#error "VSWRIST_W_DIR (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_ARMED
#error "VSWRIST_W_ARMED (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_PASSED
#error "VSWRIST_W_PASSED (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_RELEASED
#error "VSWRIST_W_RELEASED (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_DUE
#error "VSWRIST_W_DUE (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_PEAK_TIME
#error "VSWRIST_W_PEAK_TIME (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_PEAK_SPEED
#error "VSWRIST_W_PEAK_SPEED (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_PEAK_VEL
#error "VSWRIST_W_PEAK_VEL (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_ACTIVE
#error "VSWRIST_W_ACTIVE (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_BODY
#error "VSWRIST_W_BODY (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_MASS_GONE
#error "VSWRIST_W_MASS_GONE (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_INERTIA_GONE
#error "VSWRIST_W_INERTIA_GONE (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_W_REACH
#error "VSWRIST_W_REACH (the release watch's row layout) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_H_METER_SIZE
#error "VSWRIST_H_METER_SIZE (handle column) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_OK
#error "VSWRIST_OK (world status) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_DIVERGED
#error "VSWRIST_DIVERGED (world status) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_MUJOCO_ERROR
#error "VSWRIST_MUJOCO_ERROR (world status) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_SYNC_KINEMATICS
#error "VSWRIST_SYNC_KINEMATICS (sync mode) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_SYNC_FORWARD
#error "VSWRIST_SYNC_FORWARD (sync mode) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_QPOS
#error "VSWRIST_F_QPOS (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_QVEL
#error "VSWRIST_F_QVEL (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_XPOS
#error "VSWRIST_F_XPOS (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_XQUAT
#error "VSWRIST_F_XQUAT (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_XMAT
#error "VSWRIST_F_XMAT (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_CVEL
#error "VSWRIST_F_CVEL (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_SENSOR
#error "VSWRIST_F_SENSOR (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_SITE_XMAT
#error "VSWRIST_F_SITE_XMAT (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#ifndef VSWRIST_F_ANGLES
#error "VSWRIST_F_ANGLES (gather field) is not defined: compile this file through vswrist_gym.model.advance_lib"
#endif
#include <math.h>
#include <stdint.h>
#include <string.h>
#include <time.h>
#include <condition_variable>
#include <mutex>
#include <thread>
#include <vector>
#include <setjmp.h>
#include <mujoco/mujoco.h>

/* MuJoCo's thread-local log handler (exported by libmujoco, declared in its private header; the Python
   bindings intercept errors the same way): an error inside a world's step jumps back to that world's
   setjmp below instead of ending the process; other messages go on to the global handler. */
extern "C" MJAPI mjfLogHandler _mjPRIVATE_setTlsLogHandler(mjfLogHandler handler);
extern "C" MJAPI mjfLogHandler _mjPRIVATE_getGlobalLogHandler(void);

static thread_local jmp_buf* tls_jump = NULL;

static void on_log(const mjLogMessage* msg) {
  if (msg->level == mjLOG_ERROR && tls_jump) longjmp(*tls_jump, 1);
  mjfLogHandler global = _mjPRIVATE_getGlobalLogHandler();
  if (global) global(msg);
}

static double thread_seconds(void) {
  struct timespec ts;
  clock_gettime(CLOCK_THREAD_CPUTIME_ID, &ts);
  return (double)ts.tv_sec + 1e-9 * (double)ts.tv_nsec;
}

/* Copies what plan names (nplan rows of field, start, count) from a synced world into its row of out. */
static void gather(const mjData* d, const uint64_t* row, const int32_t* plan, int nplan, double* out) {
  for (int p = 0; p < nplan; p++) {
    const int32_t f = plan[3 * p], start = plan[3 * p + 1], n = plan[3 * p + 2];
    if (f == VSWRIST_F_ANGLES) {
      /* the coupler's RUD and FE (sim.coupler_angles): asin of -R[2, 0] clamped as Python's max(-1, min(1, .)),
         atan2(R[1, 0], R[0, 0]) */
      const mjtNum* R = d->xmat + start;
      double s = -R[6];
      s = s < 1.0 ? s : 1.0;
      s = s > -1.0 ? s : -1.0;
      out[0] = asin(s);
      out[1] = atan2(R[3], R[0]);
      out += 2;
      continue;
    }
    const mjtNum* src = f == VSWRIST_F_QPOS ? d->qpos : f == VSWRIST_F_QVEL ? d->qvel : f == VSWRIST_F_XPOS ? d->xpos
                      : f == VSWRIST_F_XQUAT ? d->xquat : f == VSWRIST_F_XMAT ? d->xmat : f == VSWRIST_F_CVEL ? d->cvel
                      : f == VSWRIST_F_SENSOR ? d->sensordata : f == VSWRIST_F_SITE_XMAT ? d->site_xmat
                      : (const mjtNum*)(uintptr_t)row[VSWRIST_H_PEAK];
    memcpy(out, src + start, sizeof(mjtNum) * n);
    out += n;
  }
}

static int diverged_now(const mjData* d) {
  return d->warning[mjWARN_BADQACC].number || d->warning[mjWARN_BADQPOS].number ||
         d->warning[mjWARN_BADQVEL].number;
}

/* How far (m) the ball's centre (body b) is behind the release plane (through w's c, normal w's dir). */
static double behind_plane(const mjData* d, const double* w, int b) {
  const mjtNum* x = d->xpos + 3 * b;
  const double* c = w + VSWRIST_W_C;
  const double* u = w + VSWRIST_W_DIR;
  return (c[0] - x[0]) * u[0] + (c[1] - x[1]) * u[1] + (c[2] - x[2]) * u[2];
}

/* The release watch: one part of a period (n substeps) of a Throw world, with its search for the release to the
   substep (envs/throw.py, ThrowEnv._advance_physics and _at_peak, in the same order; w: the world's watch row,
   whose flags and peak this updates). A part is plain (n substeps, no watch) before the forward swing (w's active
   0), after the release once the ball's mass is gone, or while the ball is farther than w's reach behind the
   release plane at the part's start (seen after mj_kinematics; the ball behind the plane arms the release). Else
   substep by substep: the ball's mass goes at the substep boundary after the release (due); the ball behind the
   plane arms, then past it passes; from then on each state's speed (after mj_step, xpos and the body velocities
   are those of the state the substep started from) is the peak, or the first slower one, which releases the ball
   at the peak. Python reads the release from the row (ThrowEnv._after_watch_worlds). Returns whether the world
   diverged (after the substep that did, as WristSim.step raises). */
static int watched_part(mjModel* m, mjData* d, double* w, int n) {
  const int b = (int)w[VSWRIST_W_BODY];
  int armed = w[VSWRIST_W_ARMED] != 0, passed = w[VSWRIST_W_PASSED] != 0;
  int released = w[VSWRIST_W_RELEASED] != 0, due = w[VSWRIST_W_DUE] != 0;
  int plain = w[VSWRIST_W_ACTIVE] == 0 || (released && !due);
  if (!plain && !released && !passed) {
    mj_kinematics(m, d);  /* xpos of the state the part starts from */
    const double behind = behind_plane(d, w, b);
    if (!armed && behind > 0.0) {
      armed = 1;
      w[VSWRIST_W_ARMED] = 1;
    }
    if (behind > w[VSWRIST_W_REACH]) plain = 1;
  }
  if (plain) {
    for (int s = 0; s < n; s++) mj_step(m, d);
    return diverged_now(d);
  }
  const double dt = m->opt.timestep;
  mjtNum vel[6];
  for (int s = 0; s < n; s++) {
    if (due) {  /* the substep boundary after the one that recognised the peak: the ball has gone */
      due = 0;
      w[VSWRIST_W_DUE] = 0;
      m->body_mass[b] = w[VSWRIST_W_MASS_GONE];
      for (int i = 0; i < 3; i++) m->body_inertia[3 * b + i] = w[VSWRIST_W_INERTIA_GONE];
    }
    mj_step(m, d);
    if (diverged_now(d)) return 1;
    if (released) continue;
    const double behind = behind_plane(d, w, b);
    if (!passed) {
      if (armed && behind <= 0.0) {
        passed = 1;
        w[VSWRIST_W_PASSED] = 1;
      } else {
        if (!armed && behind > 0.0) {
          armed = 1;
          w[VSWRIST_W_ARMED] = 1;
        }
        continue;
      }
    }
    mj_objectVelocity(m, d, mjOBJ_BODY, b, vel, 0);
    const double speed = sqrt(vel[3] * vel[3] + vel[4] * vel[4] + vel[5] * vel[5]);
    if (speed < w[VSWRIST_W_PEAK_SPEED]) {  /* slower than the peak (none yet: 0): released at the peak */
      released = due = 1;
      w[VSWRIST_W_RELEASED] = 1;
      w[VSWRIST_W_DUE] = 1;
    } else {
      w[VSWRIST_W_PEAK_TIME] = d->time - dt;
      w[VSWRIST_W_PEAK_SPEED] = speed;
      for (int i = 0; i < 3; i++) w[VSWRIST_W_PEAK_VEL + i] = vel[3 + i];
    }
  }
  return 0;
}

/* worlds[0..count): rows of the handle table h (stride HANDLE_COLUMNS); theta: count x 4 motor references in
   the order of worlds; ctrl_idx: the 4 ctrl addresses (the same layout in every world); status: count
   results; step_seconds: NULL, or count accumulators of the thread CPU time inside mj_step; plan/out: NULL,
   or the gather plan and count rows of out_cols doubles, written for the worlds whose status is OK (what the
   environment reads after the step, copied here on the world's thread instead of world by world in Python).
   Returns the number of worlds whose status is not OK. */
extern "C" int vswrist_advance(const uint64_t* h, const int32_t* worlds, int count, const double* theta,
                               const int32_t* ctrl_idx, int nstep, int sync, int32_t* status,
                               double* step_seconds, const int32_t* plan, int nplan, double* out,
                               int out_cols) {
  volatile int nbad = 0;
  jmp_buf jump;
  mjfLogHandler previous = _mjPRIVATE_setTlsLogHandler(on_log);
  for (volatile int k = 0; k < count; k++) {
    const uint64_t* row = h + (int64_t)worlds[k] * VSWRIST_HANDLE_COLUMNS;
    mjModel* m = (mjModel*)(uintptr_t)row[VSWRIST_H_MODEL];
    mjData* d = (mjData*)(uintptr_t)row[VSWRIST_H_DATA];
    status[k] = VSWRIST_OK;
    tls_jump = &jump;
    if (setjmp(jump)) {  /* MuJoCo raised an error in this world: its state is undefined, reported */
      status[k] = VSWRIST_MUJOCO_ERROR;
      nbad++;
      continue;
    }
    {
      /* latency: the first substeps of the period run on the previous references (as VSWristEnv._advance
         runs them in two calls, the divergence checked after each) */
      const int nlat = (int)row[VSWRIST_H_LATENCY];
      double* watch = (double*)(uintptr_t)row[VSWRIST_H_WATCH];  /* Throw's release watch, or NULL */
      *(mjtNum*)(uintptr_t)row[VSWRIST_H_PEAK] = 0;
      if (row[VSWRIST_H_METER]) memset((void*)(uintptr_t)row[VSWRIST_H_METER], 0, sizeof(mjtNum) * row[VSWRIST_H_METER_SIZE]);
      double t0 = step_seconds ? thread_seconds() : 0.0;
      int diverged = 0;
      for (int part = nlat > 0 ? 0 : 1; part < 2 && !diverged; part++) {
        if (part == 1)
          for (int j = 0; j < 4; j++) d->ctrl[ctrl_idx[j]] = theta[4 * k + j];
        const int n = part == 0 ? nlat : nstep - nlat;
        if (watch) {
          diverged = watched_part(m, d, watch, n);
        } else {
          for (int s = 0; s < n; s++) mj_step(m, d);
          diverged = diverged_now(d);
        }
      }
      if (step_seconds) step_seconds[k] += thread_seconds() - t0;
      if (diverged) {
        status[k] = VSWRIST_DIVERGED;
        nbad++;
        continue;
      }
      if (sync == VSWRIST_SYNC_KINEMATICS) {
        mj_kinematics(m, d);
        mj_comPos(m, d);
        mj_comVel(m, d);
      } else if (sync == VSWRIST_SYNC_FORWARD) {
        m->opt.disableflags &= ~mjDSBL_SENSOR;
        mj_forward(m, d);
        m->opt.disableflags |= mjDSBL_SENSOR;
      }
      if (out) gather(d, row, plan, nplan, out + (int64_t)k * out_cols);
    }
  }
  tls_jump = NULL;
  _mjPRIVATE_setTlsLogHandler(previous);
  return nbad;
}

/* A pool of threads that runs one batch's chunks (positions bounds[c]..bounds[c+1] of worlds), claimed in
   order of c, without Python. The caller submits, then works on the finished chunks (their rewards and
   observations, in Python) and, when none is finished, steps an unclaimed chunk itself (run_one) or waits:
   every call is a ctypes call, so the caller holds no GIL meanwhile, and caller + pool threads = the cores.
   Only chunks below ``released`` may be claimed: the caller can submit the first chunks while it still
   computes the motor references of the others, then release those (the lock orders its writes to theta
   before any thread's reads). One job at a time: the caller waits for all released chunks before the next
   submit. */
struct Job {
  const uint64_t* h; const int32_t* worlds; const double* theta; const int32_t* ctrl_idx;
  int nstep, sync; int32_t* status; double* seconds; const int32_t* bounds; int nchunks, released;
  const int32_t* plan; int nplan; double* out; int out_cols;
};

struct Pool {
  std::vector<std::thread> threads;
  std::mutex mu;
  std::condition_variable work, done_cv;
  Job job{};
  int next = 0, ndone = 0;
  bool stop = false;
  std::vector<char> done;

  /* runs chunk c (claimed under the lock, which lk holds on entry and on return) */
  void run_chunk(std::unique_lock<std::mutex>& lk, int c) {
    Job j = job;
    lk.unlock();
    int lo = j.bounds[c], hi = j.bounds[c + 1];
    vswrist_advance(j.h, j.worlds + lo, hi - lo, j.theta + 4 * lo, j.ctrl_idx, j.nstep, j.sync, j.status + lo,
                    j.seconds ? j.seconds + lo : NULL, j.plan, j.nplan,
                    j.out ? j.out + (int64_t)lo * j.out_cols : NULL, j.out_cols);
    lk.lock();
    done[c] = 1;
    ndone++;
    done_cv.notify_all();
  }

  void run() {
    std::unique_lock<std::mutex> lk(mu);
    for (;;) {
      work.wait(lk, [&] { return stop || next < job.released; });
      if (stop) return;
      run_chunk(lk, next++);
    }
  }
};

extern "C" void* vswrist_pool_new(int nthreads) {
  Pool* p = new Pool();
  for (int i = 0; i < nthreads; i++) p->threads.emplace_back([p] { p->run(); });
  return p;
}

extern "C" void vswrist_pool_free(void* pool) {
  Pool* p = (Pool*)pool;
  {
    std::lock_guard<std::mutex> lk(p->mu);
    p->stop = true;
  }
  p->work.notify_all();
  for (auto& t : p->threads) t.join();
  delete p;
}

extern "C" void vswrist_pool_submit(void* pool, const uint64_t* h, const int32_t* worlds, const double* theta,
                                    const int32_t* ctrl_idx, int nstep, int sync, int32_t* status,
                                    double* seconds, const int32_t* bounds, int nchunks, int released,
                                    const int32_t* plan, int nplan, double* out, int out_cols) {
  Pool* p = (Pool*)pool;
  {
    std::lock_guard<std::mutex> lk(p->mu);
    p->job = Job{h, worlds, theta, ctrl_idx, nstep, sync, status, seconds, bounds, nchunks,
                 released < nchunks ? released : nchunks, plan, nplan, out, out_cols};
    p->next = 0;
    p->ndone = 0;
    p->done.assign(nchunks, 0);
  }
  p->work.notify_all();
}

/* Lets chunks below upto be claimed. */
extern "C" void vswrist_pool_release(void* pool, int upto) {
  Pool* p = (Pool*)pool;
  {
    std::lock_guard<std::mutex> lk(p->mu);
    if (upto > p->job.nchunks) upto = p->job.nchunks;
    if (upto > p->job.released) p->job.released = upto;
  }
  p->work.notify_all();
}

/* Claims the next unclaimed released chunk and runs it on the calling thread, unless no more than ``keep``
   are left unclaimed (those stay for the pool's threads); returns it, or -1. */
extern "C" int vswrist_pool_run_one(void* pool, int keep) {
  Pool* p = (Pool*)pool;
  std::unique_lock<std::mutex> lk(p->mu);
  if (p->next >= p->job.released - (keep > 0 ? keep : 0)) return -1;
  int c = p->next++;
  p->run_chunk(lk, c);
  return c;
}

/* Copies the chunks' done flags into out (nchunks bytes); returns how many are done. */
extern "C" int vswrist_pool_ready(void* pool, char* out) {
  Pool* p = (Pool*)pool;
  std::lock_guard<std::mutex> lk(p->mu);
  memcpy(out, p->done.data(), p->done.size());
  return p->ndone;
}

/* Blocks until chunk c is done (c < 0: every released chunk; one never released is never run). */
extern "C" void vswrist_pool_wait(void* pool, int c) {
  Pool* p = (Pool*)pool;
  std::unique_lock<std::mutex> lk(p->mu);
  if (c < 0)
    p->done_cv.wait(lk, [&] { return p->ndone == p->job.released; });
  else
    p->done_cv.wait(lk, [&] { return p->done[c] != 0; });
}
