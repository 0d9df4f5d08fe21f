"""One control period of many worlds in one C call: ``advance(...)`` steps each world's ``mj_step`` substeps
and brings what the environment reads up to date, for a chunk of a batch's worlds, without the GIL.

Why: a batch (``envs.batch.VSWristVectorEnv``) steps its worlds on threads. Through the bindings every world
costs several GIL hand-overs (``mj_step``, then ``mj_kinematics``/``mj_comPos``/``mj_comVel`` or
``mj_forward``, each releasing and re-taking the lock) and a few microseconds of Python between them; threads
then queue for the lock, and a thread that runs Python (the batch's rewards and observations) holds it for
milliseconds. Here a thread makes one ``ctypes`` call for its whole chunk (``ctypes`` releases the GIL for the
call), so the physics of one chunk overlaps the Python of another.

Per world the call does what ``VSWristEnv._advance`` does through ``WristSim`` (and the contact meter of
``shared.PeriodMeanForce``), in the same order, so the numbers are the same to the bit: write the motor
references into ``ctrl``, zero the loop-closure peak and the contact meter's window, ``nstep`` calls of
``mj_step``, the divergence check on MuJoCo's NaN warnings (a diverged world is left as MuJoCo reset it,
unsynced, as ``WristSim.step`` raises before its sync), then the sync: ``mj_kinematics`` + ``mj_comPos`` +
``mj_comVel`` (``sync_kinematics``) or ``mj_forward`` with the sensors enabled (``WristSim._forward``).
Then, with a gather plan, it copies what the environment reads after the step (joint positions, the coupler's
pose and velocity, the loop-closure bodies, sensors: ``VSWristVectorEnv._gather_plan``) into the world's row of
one array, on the world's thread, so that the batch reads every world's simulator in one NumPy array.

An error MuJoCo raises inside a world (``mju_error``) is intercepted as the Python bindings intercept it (a
thread-local log handler that jumps back to the world's ``setjmp``): that world's status says so and the
batch raises ``mujoco.FatalError`` naming it, as the bindings' ``mj_step`` would raise it; the process
lives on. The library is C++ (its thread pool); it is compiled once per MuJoCo version with the system C++
compiler into the cache directory of the plugin library; where there is none, ``load()`` returns None and
the batch steps world by world through ``WristSim``.
"""

from __future__ import annotations

import ctypes
import os
from pathlib import Path

import numpy as np

from .plugin_lib import build_library

# columns of the handle table (one row per world, uint64): what the call needs of each world's MjModel/MjData
H_MODEL, H_DATA, H_PEAK, H_METER, H_METER_SIZE = range(5)
HANDLE_COLUMNS = 5

# ``status`` of a world after a call
OK, DIVERGED, MUJOCO_ERROR = 0, 1, 2

SYNC_NONE, SYNC_KINEMATICS, SYNC_FORWARD = 0, 1, 2

# what a gather plan (``plan``: rows of (field, start, count)) copies from each synced world into its row of ``out``:
# MjData arrays (flattened: xpos[b] starts at 3 b) and the loop-closure peak (start and count 0, 1)
F_QPOS, F_QVEL, F_XPOS, F_XQUAT, F_XMAT, F_CVEL, F_SENSOR, F_SITE_XMAT, F_PEAK = range(9)

SOURCE = r"""
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
    const mjtNum* src = f == @F_QPOS@ ? d->qpos : f == @F_QVEL@ ? d->qvel : f == @F_XPOS@ ? d->xpos
                      : f == @F_XQUAT@ ? d->xquat : f == @F_XMAT@ ? d->xmat : f == @F_CVEL@ ? d->cvel
                      : f == @F_SENSOR@ ? d->sensordata : f == @F_SITE_XMAT@ ? d->site_xmat
                      : (const mjtNum*)(uintptr_t)row[@PEAK@];
    memcpy(out, src + start, sizeof(mjtNum) * n);
    out += n;
  }
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
    const uint64_t* row = h + (int64_t)worlds[k] * @COLUMNS@;
    mjModel* m = (mjModel*)(uintptr_t)row[@MODEL@];
    mjData* d = (mjData*)(uintptr_t)row[@DATA@];
    status[k] = @OK@;
    tls_jump = &jump;
    if (setjmp(jump)) {  /* MuJoCo raised an error in this world: its state is undefined, reported */
      status[k] = @MUJOCO_ERROR@;
      nbad++;
      continue;
    }
    {
      for (int j = 0; j < 4; j++) d->ctrl[ctrl_idx[j]] = theta[4 * k + j];
      *(mjtNum*)(uintptr_t)row[@PEAK@] = 0;
      if (row[@METER@]) memset((void*)(uintptr_t)row[@METER@], 0, sizeof(mjtNum) * row[@METER_SIZE@]);
      double t0 = step_seconds ? thread_seconds() : 0.0;
      for (int s = 0; s < nstep; s++) mj_step(m, d);
      if (step_seconds) step_seconds[k] += thread_seconds() - t0;
      if (d->warning[mjWARN_BADQACC].number || d->warning[mjWARN_BADQPOS].number ||
          d->warning[mjWARN_BADQVEL].number) {
        status[k] = @DIVERGED@;
        nbad++;
        continue;
      }
      if (sync == @SYNC_KINEMATICS@) {
        mj_kinematics(m, d);
        mj_comPos(m, d);
        mj_comVel(m, d);
      } else if (sync == @SYNC_FORWARD@) {
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
"""
for _key, _value in {"COLUMNS": HANDLE_COLUMNS, "MODEL": H_MODEL, "DATA": H_DATA, "PEAK": H_PEAK, "METER": H_METER,
                     "METER_SIZE": H_METER_SIZE, "OK": OK, "DIVERGED": DIVERGED, "MUJOCO_ERROR": MUJOCO_ERROR,
                     "SYNC_KINEMATICS": SYNC_KINEMATICS, "SYNC_FORWARD": SYNC_FORWARD, "F_QPOS": F_QPOS,
                     "F_QVEL": F_QVEL, "F_XPOS": F_XPOS, "F_XQUAT": F_XQUAT, "F_XMAT": F_XMAT, "F_CVEL": F_CVEL,
                     "F_SENSOR": F_SENSOR, "F_SITE_XMAT": F_SITE_XMAT}.items():
    SOURCE = SOURCE.replace(f"@{_key}@", str(_value))

_lib = None  # the loaded library's function, False where it cannot be built


def compile_library() -> Path:
    """Compile the library (once; atomically, safe with parallel processes) and return its path."""
    return build_library(SOURCE, "vswrist_advance", ".cc", ("CXX", "g++", "c++", "clang++"), ["-pthread"])


def load():
    """The compiled library (ctypes), or None where it cannot be built (no C++ compiler, or
    ``VSWRIST_NATIVE=0``): callers then step world by world."""
    global _lib
    if _lib is None:
        _lib = False
        if os.environ.get("VSWRIST_NATIVE", "1") != "0":
            try:
                lib = ctypes.CDLL(str(compile_library()))
            except (OSError, RuntimeError):
                pass
            else:
                p, i = ctypes.c_void_p, ctypes.c_int
                lib.vswrist_advance.argtypes = [p, p, i, p, p, i, i, p, p, p, i, p, i]
                lib.vswrist_advance.restype = i
                lib.vswrist_pool_new.argtypes = [i]
                lib.vswrist_pool_new.restype = p
                lib.vswrist_pool_free.argtypes = [p]
                lib.vswrist_pool_free.restype = None
                lib.vswrist_pool_submit.argtypes = [p, p, p, p, p, i, i, p, p, p, i, i, p, i, p, i]
                lib.vswrist_pool_submit.restype = None
                lib.vswrist_pool_release.argtypes = [p, i]
                lib.vswrist_pool_release.restype = None
                lib.vswrist_pool_wait.argtypes = [p, i]
                lib.vswrist_pool_wait.restype = None
                lib.vswrist_pool_run_one.argtypes = [p, i]
                lib.vswrist_pool_run_one.restype = i
                lib.vswrist_pool_ready.argtypes = [p, p]
                lib.vswrist_pool_ready.restype = i
                _lib = lib
    return _lib or None


def _ptr(a: np.ndarray | None) -> int:
    return 0 if a is None else a.ctypes.data


def advance(lib, handles: np.ndarray, worlds: np.ndarray, theta: np.ndarray, ctrl_idx: np.ndarray, nstep: int,
            sync: int, status: np.ndarray, step_seconds: np.ndarray | None = None, plan: np.ndarray | None = None,
            out: np.ndarray | None = None) -> int:
    """One call over ``worlds`` (int32, indices into ``handles``) on the calling thread; ``theta``
    (len(worlds), 4) float64 C-contiguous, ``status`` int32 of len(worlds), written; ``step_seconds``: None or
    float64 accumulators per world; ``plan`` (int32 (k, 3)) and ``out`` (float64 C-contiguous (len(worlds),
    columns)): the gather. Returns the number of worlds not OK."""
    return lib.vswrist_advance(handles.ctypes.data, worlds.ctypes.data, len(worlds), theta.ctypes.data,
                               ctrl_idx.ctypes.data, nstep, sync, status.ctypes.data, _ptr(step_seconds),
                               *_gather_args(plan, out))


def _gather_args(plan: np.ndarray | None, out: np.ndarray | None) -> tuple:
    if out is None:
        return 0, 0, 0, 0
    assert plan.dtype == np.int32 and plan.flags.c_contiguous and out.dtype == np.float64 \
        and out.flags.c_contiguous and out.shape[1] == int(plan[:, 2].sum())
    return plan.ctypes.data, len(plan), out.ctypes.data, out.shape[1]


class Pool:
    """``threads`` C++ threads that step a batch's chunks of worlds (see the source). ``submit`` returns at
    once; ``run_one(keep)`` steps the next unclaimed released chunk on the calling thread (its index), unless
    at most ``keep`` are left unclaimed (-1); ``ready()`` gives the chunks' done flags; ``wait(c)`` blocks until
    chunk c is done, ``wait()`` until all released ones are. The arrays given to ``submit`` are kept referenced
    until the next submit, so they outlive the threads' use of them."""

    def __init__(self, lib, threads: int):
        self._lib, self.threads, self.pid = lib, threads, os.getpid()
        self._p = lib.vswrist_pool_new(threads)
        self._keep: tuple = ()

    def submit(self, handles, worlds, theta, ctrl_idx, nstep, sync, status, step_seconds, bounds,
               released: int | None = None, plan: np.ndarray | None = None, out: np.ndarray | None = None) -> None:
        """``released``: how many of the first chunks may run now (default all); ``release`` lets the others
        run once their rows of ``theta`` are written. ``plan``/``out``: the gather, as ``advance``."""
        self._keep = (handles, worlds, theta, ctrl_idx, status, step_seconds, plan, out, bounds)
        k = len(bounds) - 1
        self._lib.vswrist_pool_submit(self._p, handles.ctypes.data, worlds.ctypes.data, theta.ctypes.data,
                                      ctrl_idx.ctypes.data, nstep, sync, status.ctypes.data, _ptr(step_seconds),
                                      bounds.ctypes.data, k, k if released is None else int(released),
                                      *_gather_args(plan, out))

    def release(self, upto: int | None = None) -> None:
        """Lets chunks below ``upto`` (default: all) be claimed."""
        self._lib.vswrist_pool_release(self._p, len(self._keep[-1]) - 1 if upto is None else int(upto))

    def wait(self, chunk: int = -1) -> None:
        self._lib.vswrist_pool_wait(self._p, chunk)

    def run_one(self, keep: int = 0) -> int:
        return self._lib.vswrist_pool_run_one(self._p, keep)

    def ready(self) -> np.ndarray:
        flags = np.zeros(len(self._keep[-1]) - 1, dtype=np.int8)
        self._lib.vswrist_pool_ready(self._p, flags.ctypes.data)
        return flags.astype(bool)

    def close(self) -> None:
        """Stops and joins the threads (after the running job, which the caller has waited for)."""
        if self._p is not None and self.pid == os.getpid():  # a forked child has no threads to join
            self._lib.vswrist_pool_free(self._p)
        self._p = None

    def __del__(self):  # a batch dropped without close(): its idle threads are joined here
        try:
            self.close()
        except Exception:  # noqa: BLE001 - interpreter shutdown: the library may be gone already
            pass
