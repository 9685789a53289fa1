// The native MuJoCo backend as an XLA FFI custom call (CPU).
//
// Per env: set (time, qpos, qvel, act), zero the solver warm-start and applied forces, hold ctrl for
// frame_skip mj_step's (stop stepping on a MuJoCo warning), then run mj_forward on the final state so
// that sensordata (and, when asked, cfrc_ext) describe the state after the step: mj_step computes
// them before it integrates, one substep behind the returned qpos.
// Why a custom call and not jax.pure_callback: no Python or numpy on the hot path, and programs
// without host callbacks can be stored in JAX's persistent compilation cache.
// Models are looked up by a content hash (an attribute of the call), so a cached program finds
// its model in a new process once the same MJCF has been registered there.

#include <mujoco/mujoco.h>

#include <algorithm>
#include <atomic>
#include <condition_variable>
#include <memory>
#include <cstdint>
#include <mutex>
#include <unordered_map>
#include <vector>

#include "xla/ffi/api/ffi.h"

namespace ffi = xla::ffi;

namespace {

struct Entry {
  const mjModel* model;
  std::mutex mu;
  std::vector<mjData*> free;  // reusable mjData: workspace only, every input is set per env
};

std::mutex registry_mu;
std::unordered_map<int64_t, Entry*> registry;

Entry* Find(int64_t id) {
  std::lock_guard<std::mutex> lock(registry_mu);
  auto it = registry.find(id);
  return it == registry.end() ? nullptr : it->second;
}

mjData* Acquire(Entry* e) {
  {
    std::lock_guard<std::mutex> lock(e->mu);
    if (!e->free.empty()) {
      mjData* d = e->free.back();
      e->free.pop_back();
      return d;
    }
  }
  return mj_makeData(e->model);
}

void Release(Entry* e, mjData* d) {
  std::lock_guard<std::mutex> lock(e->mu);
  e->free.push_back(d);
}

// Inputs that are not part of hdt's state are reset so that a result never depends on which
// pooled mjData ran the env before.
void SetState(const mjModel* m, mjData* d, float time, const float* qpos, const float* qvel,
              const float* act) {
  d->time = time;
  for (int i = 0; i < m->nq; i++) d->qpos[i] = qpos[i];
  for (int i = 0; i < m->nv; i++) d->qvel[i] = qvel[i];
  for (int i = 0; i < m->na; i++) d->act[i] = act[i];
  mju_zero(d->qacc_warmstart, m->nv);
  mju_zero(d->qfrc_applied, m->nv);
  mju_zero(d->xfrc_applied, 6 * m->nbody);
  for (int i = 0; i < mjNWARNING; i++) d->warning[i].number = 0;
}

// Observables of the state in d: forward dynamics first, so sensors read the final state.
void GetState(const mjModel* m, mjData* d, bool cfrc, float* time, float* qpos, float* qvel,
              float* act, float* sens, float* cfrc_ext) {
  mju_zero(d->qacc_warmstart, m->nv);  // as every env step starts: the result never depends on history
  mj_forward(m, d);
  *time = static_cast<float>(d->time);
  for (int i = 0; i < m->nq; i++) qpos[i] = static_cast<float>(d->qpos[i]);
  for (int i = 0; i < m->nv; i++) qvel[i] = static_cast<float>(d->qvel[i]);
  for (int i = 0; i < m->na; i++) act[i] = static_cast<float>(d->act[i]);
  for (int i = 0; i < m->nsensordata; i++) sens[i] = static_cast<float>(d->sensordata[i]);
  if (cfrc) {
    mj_rnePostConstraint(m, d);  // not part of mj_forward unless a sensor needs it
    for (int i = 0; i < 6 * m->nbody; i++) cfrc_ext[i] = static_cast<float>(d->cfrc_ext[i]);
  }
}

bool Warned(const mjData* d) {
  for (int i = 0; i < mjNWARNING; i++) {
    if (d->warning[i].number) return true;
  }
  return false;
}

// Runs fn(d, i) for i in [0, n) on XLA's intra-op thread pool, each chunk with its own mjData.
// Own threads would compete with XLA's (measured: slower than one thread on 2 cores). Chunks are
// claimed from a counter by the caller and by the scheduled tasks alike, so the caller never waits
// for a task the pool has not started (no deadlock when the pool is busy with other calls).
struct Job {
  std::atomic<int64_t> next{0}, done{0};
  int64_t nchunk = 0;
  std::mutex mu;
  std::condition_variable cv;
};

template <typename Fn>
void ParallelFor(Entry* e, int64_t n, ffi::ThreadPool* pool, Fn fn) {
  int64_t nthread = pool ? std::max<int64_t>(1, pool->num_threads()) : 1;
  auto job = std::make_shared<Job>();
  job->nchunk = std::max<int64_t>(1, std::min(n, 2 * nthread));
  auto run = [e, n, job, &fn]() {
    for (int64_t c; (c = job->next.fetch_add(1)) < job->nchunk;) {
      mjData* d = Acquire(e);
      for (int64_t i = c * n / job->nchunk; i < (c + 1) * n / job->nchunk; i++) fn(d, i);
      Release(e, d);
      if (job->done.fetch_add(1) + 1 == job->nchunk) {
        std::lock_guard<std::mutex> lock(job->mu);
        job->cv.notify_all();
      }
    }
  };
  // Late tasks find no chunk left and return without touching fn (which lives on our stack).
  for (int64_t w = 1; w < std::min(nthread, job->nchunk); w++) pool->Schedule(decltype(run)(run));
  run();
  std::unique_lock<std::mutex> lock(job->mu);
  job->cv.wait(lock, [&] { return job->done.load() == job->nchunk; });
}

ffi::Error CheckSizes(const mjModel* m, size_t n, size_t nq, size_t nv, size_t na, size_t ns,
                      size_t nc, bool cfrc) {
  if (nq != n * m->nq || nv != n * m->nv || na != n * m->na || ns != n * m->nsensordata ||
      nc != (cfrc ? n * 6 * m->nbody : 0)) {
    return ffi::Error::InvalidArgument("hdt native physics: buffer sizes do not match the model");
  }
  return ffi::Error::Success();
}

ffi::Error StepImpl(ffi::ThreadPool pool, int64_t model_id, int64_t frame_skip, int64_t cfrc,
                    ffi::Buffer<ffi::F32> time, ffi::Buffer<ffi::F32> qpos,
                    ffi::Buffer<ffi::F32> qvel, ffi::Buffer<ffi::F32> act,
                    ffi::Buffer<ffi::F32> ctrl, ffi::Buffer<ffi::F32> active,
                    ffi::ResultBuffer<ffi::F32> time_out, ffi::ResultBuffer<ffi::F32> qpos_out,
                    ffi::ResultBuffer<ffi::F32> qvel_out, ffi::ResultBuffer<ffi::F32> act_out,
                    ffi::ResultBuffer<ffi::F32> sens_out, ffi::ResultBuffer<ffi::F32> cfrc_out) {
  Entry* e = Find(model_id);
  if (!e) return ffi::Error::InvalidArgument("hdt native physics: model not registered");
  const mjModel* m = e->model;
  int64_t n = time.element_count();
  ffi::Error err = CheckSizes(m, n, qpos.element_count(), qvel.element_count(),
                              act.element_count(), sens_out->element_count(),
                              cfrc_out->element_count(), cfrc != 0);
  if (err.failure()) return err;
  if (ctrl.element_count() != static_cast<size_t>(n * m->nu)) {
    return ffi::Error::InvalidArgument("hdt native physics: ctrl size does not match the model");
  }
  if (active.element_count() != static_cast<size_t>(n)) {
    return ffi::Error::InvalidArgument("hdt native physics: active mask size does not match the batch");
  }
  const float *t_in = time.typed_data(), *qp = qpos.typed_data(), *qv = qvel.typed_data(),
              *ac = act.typed_data(), *u = ctrl.typed_data(), *on = active.typed_data();
  float *t_out = time_out->typed_data(), *qp_out = qpos_out->typed_data(),
        *qv_out = qvel_out->typed_data(), *a_out = act_out->typed_data(),
        *s_out = sens_out->typed_data(), *c_out = cfrc_out->typed_data();
  const int64_t nc = cfrc ? 6 * m->nbody : 0;
  // Inactive envs (an HL step's LL loop that already stopped) are passed through unstepped, with
  // zero sensors and forces; only the active ones are stepped, compacted so the threads share them
  // evenly.
  std::vector<int64_t> rows;
  rows.reserve(n);
  for (int64_t i = 0; i < n; i++) {
    if (on[i] != 0.0f) {
      rows.push_back(i);
      continue;
    }
    t_out[i] = t_in[i];
    std::copy(qp + i * m->nq, qp + (i + 1) * m->nq, qp_out + i * m->nq);
    std::copy(qv + i * m->nv, qv + (i + 1) * m->nv, qv_out + i * m->nv);
    std::copy(ac + i * m->na, ac + (i + 1) * m->na, a_out + i * m->na);
    std::fill(s_out + i * m->nsensordata, s_out + (i + 1) * m->nsensordata, 0.0f);
    std::fill(c_out + i * nc, c_out + (i + 1) * nc, 0.0f);
  }
  if (rows.empty()) return ffi::Error::Success();
  ParallelFor(e, static_cast<int64_t>(rows.size()), &pool, [&](mjData* d, int64_t j) {
    int64_t i = rows[j];
    SetState(m, d, t_in[i], qp + i * m->nq, qv + i * m->nv, ac + i * m->na);
    for (int k = 0; k < m->nu; k++) d->ctrl[k] = u[i * m->nu + k];
    for (int64_t s = 0; s < frame_skip && !Warned(d); s++) mj_step(m, d);
    GetState(m, d, cfrc != 0, t_out + i, qp_out + i * m->nq, qv_out + i * m->nv,
             a_out + i * m->na, s_out + i * m->nsensordata, c_out + i * nc);
  });
  return ffi::Error::Success();
}

ffi::Error ForwardImpl(int64_t model_id, int64_t cfrc, ffi::Buffer<ffi::F32> time,
                       ffi::Buffer<ffi::F32> qpos, ffi::Buffer<ffi::F32> qvel,
                       ffi::Buffer<ffi::F32> act, ffi::ResultBuffer<ffi::F32> time_out,
                       ffi::ResultBuffer<ffi::F32> qpos_out, ffi::ResultBuffer<ffi::F32> qvel_out,
                       ffi::ResultBuffer<ffi::F32> act_out, ffi::ResultBuffer<ffi::F32> sens_out,
                       ffi::ResultBuffer<ffi::F32> cfrc_out) {
  Entry* e = Find(model_id);
  if (!e) return ffi::Error::InvalidArgument("hdt native physics: model not registered");
  const mjModel* m = e->model;
  int64_t n = time.element_count();
  ffi::Error err = CheckSizes(m, n, qpos.element_count(), qvel.element_count(),
                              act.element_count(), sens_out->element_count(),
                              cfrc_out->element_count(), cfrc != 0);
  if (err.failure()) return err;
  const float *t_in = time.typed_data(), *qp = qpos.typed_data(), *qv = qvel.typed_data(),
              *ac = act.typed_data();
  float *t_out = time_out->typed_data(), *qp_out = qpos_out->typed_data(),
        *qv_out = qvel_out->typed_data(), *a_out = act_out->typed_data(),
        *s_out = sens_out->typed_data(), *c_out = cfrc_out->typed_data();
  const int64_t nc = cfrc ? 6 * m->nbody : 0;
  ParallelFor(e, n, nullptr, [&](mjData* d, int64_t i) {
    SetState(m, d, t_in[i], qp + i * m->nq, qv + i * m->nv, ac + i * m->na);
    mju_zero(d->ctrl, m->nu);
    GetState(m, d, cfrc != 0, t_out + i, qp_out + i * m->nq, qv_out + i * m->nv,
             a_out + i * m->na, s_out + i * m->nsensordata, c_out + i * nc);
  });
  return ffi::Error::Success();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(HdtPhysicsStep, StepImpl,
                              ffi::Ffi::Bind()
                                  .Ctx<ffi::ThreadPool>()
                                  .Attr<int64_t>("model_id")
                                  .Attr<int64_t>("frame_skip")
                                  .Attr<int64_t>("cfrc")  // 1: also return cfrc_ext
                                  .Arg<ffi::Buffer<ffi::F32>>()  // time
                                  .Arg<ffi::Buffer<ffi::F32>>()  // qpos
                                  .Arg<ffi::Buffer<ffi::F32>>()  // qvel
                                  .Arg<ffi::Buffer<ffi::F32>>()  // act
                                  .Arg<ffi::Buffer<ffi::F32>>()  // ctrl
                                  .Arg<ffi::Buffer<ffi::F32>>()  // active (1 = step, 0 = pass through)
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>());

XLA_FFI_DEFINE_HANDLER_SYMBOL(HdtPhysicsForward, ForwardImpl,
                              ffi::Ffi::Bind()
                                  .Attr<int64_t>("model_id")
                                  .Attr<int64_t>("cfrc")
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Arg<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>()
                                  .Ret<ffi::Buffer<ffi::F32>>());

// Registers a model under its content hash. The caller keeps the MjModel alive for the process.
// Returns 1 if newly registered, 0 if the id was already known.
extern "C" int HdtRegisterModel(int64_t model_id, const mjModel* model) {
  std::lock_guard<std::mutex> lock(registry_mu);
  if (registry.count(model_id)) return 0;
  Entry* e = new Entry();
  e->model = model;
  registry[model_id] = e;
  return 1;
}
