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
#include <utility>
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

// One call's state buffers as raw pointers, checked against the registered model (step and forward).
struct Batch {
  Entry* e = nullptr;
  const mjModel* m = nullptr;
  int64_t n = 0, nc = 0;  // envs; cfrc_ext numbers per env (0 when not asked)
  const float *t_in = nullptr, *qp = nullptr, *qv = nullptr, *ac = nullptr;
  float *t_out = nullptr, *qp_out = nullptr, *qv_out = nullptr, *a_out = nullptr, *s_out = nullptr,
        *c_out = nullptr;
};

ffi::Error Open(int64_t model_id, bool cfrc, ffi::Buffer<ffi::F32>& time, ffi::Buffer<ffi::F32>& qpos,
                ffi::Buffer<ffi::F32>& qvel, ffi::Buffer<ffi::F32>& act, ffi::ResultBuffer<ffi::F32>& time_out,
                ffi::ResultBuffer<ffi::F32>& qpos_out, ffi::ResultBuffer<ffi::F32>& qvel_out,
                ffi::ResultBuffer<ffi::F32>& act_out, ffi::ResultBuffer<ffi::F32>& sens_out,
                ffi::ResultBuffer<ffi::F32>& cfrc_out, Batch* b) {
  b->e = Find(model_id);
  if (!b->e) return ffi::Error::InvalidArgument("hdt native physics: model not registered");
  const mjModel* m = b->m = b->e->model;
  size_t n = time.element_count();
  b->n = static_cast<int64_t>(n);
  b->nc = cfrc ? 6 * m->nbody : 0;
  if (qpos.element_count() != n * m->nq || qvel.element_count() != n * m->nv ||
      act.element_count() != n * m->na || sens_out->element_count() != n * m->nsensordata ||
      cfrc_out->element_count() != n * b->nc) {
    return ffi::Error::InvalidArgument("hdt native physics: buffer sizes do not match the model");
  }
  b->t_in = time.typed_data(), b->qp = qpos.typed_data(), b->qv = qvel.typed_data(), b->ac = act.typed_data();
  b->t_out = time_out->typed_data(), b->qp_out = qpos_out->typed_data(), b->qv_out = qvel_out->typed_data();
  b->a_out = act_out->typed_data(), b->s_out = sens_out->typed_data(), b->c_out = cfrc_out->typed_data();
  return ffi::Error::Success();
}

// The state of env ``i`` of ``b`` into ``d``, and back from it into the outputs.
void Load(const Batch& b, mjData* d, int64_t i) {
  const mjModel* m = b.m;
  SetState(m, d, b.t_in[i], b.qp + i * m->nq, b.qv + i * m->nv, b.ac + i * m->na);
}

void Store(const Batch& b, mjData* d, int64_t i) {
  const mjModel* m = b.m;
  GetState(m, d, b.nc != 0, b.t_out + i, b.qp_out + i * m->nq, b.qv_out + i * m->nv, b.a_out + i * m->na,
           b.s_out + i * m->nsensordata, b.c_out + i * b.nc);
}

ffi::Error StepImpl(ffi::ThreadPool pool, int64_t model_id, int64_t frame_skip, int64_t cfrc,
                    ffi::Buffer<ffi::F32> time, ffi::Buffer<ffi::F32> qpos,
                    ffi::Buffer<ffi::F32> qvel, ffi::Buffer<ffi::F32> act,
                    ffi::Buffer<ffi::F32> ctrl, ffi::Buffer<ffi::F32> active,
                    ffi::ResultBuffer<ffi::F32> time_out, ffi::ResultBuffer<ffi::F32> qpos_out,
                    ffi::ResultBuffer<ffi::F32> qvel_out, ffi::ResultBuffer<ffi::F32> act_out,
                    ffi::ResultBuffer<ffi::F32> sens_out, ffi::ResultBuffer<ffi::F32> cfrc_out) {
  Batch b;
  ffi::Error err = Open(model_id, cfrc != 0, time, qpos, qvel, act, time_out, qpos_out, qvel_out, act_out,
                        sens_out, cfrc_out, &b);
  if (err.failure()) return err;
  const mjModel* m = b.m;
  const int64_t n = b.n;
  if (ctrl.element_count() != static_cast<size_t>(n * m->nu)) {
    return ffi::Error::InvalidArgument("hdt native physics: ctrl size does not match the model");
  }
  if (active.element_count() != static_cast<size_t>(n)) {
    return ffi::Error::InvalidArgument("hdt native physics: active mask size does not match the batch");
  }
  const float *u = ctrl.typed_data(), *on = active.typed_data();
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
    b.t_out[i] = b.t_in[i];
    std::copy(b.qp + i * m->nq, b.qp + (i + 1) * m->nq, b.qp_out + i * m->nq);
    std::copy(b.qv + i * m->nv, b.qv + (i + 1) * m->nv, b.qv_out + i * m->nv);
    std::copy(b.ac + i * m->na, b.ac + (i + 1) * m->na, b.a_out + i * m->na);
    std::fill(b.s_out + i * m->nsensordata, b.s_out + (i + 1) * m->nsensordata, 0.0f);
    std::fill(b.c_out + i * b.nc, b.c_out + (i + 1) * b.nc, 0.0f);
  }
  if (rows.empty()) return ffi::Error::Success();
  ParallelFor(b.e, static_cast<int64_t>(rows.size()), &pool, [&](mjData* d, int64_t j) {
    int64_t i = rows[j];
    Load(b, d, i);
    for (int k = 0; k < m->nu; k++) d->ctrl[k] = u[i * m->nu + k];
    for (int64_t s = 0; s < frame_skip && !Warned(d); s++) mj_step(m, d);
    Store(b, d, i);
  });
  return ffi::Error::Success();
}

ffi::Error ForwardImpl(int64_t model_id, int64_t cfrc, ffi::Buffer<ffi::F32> time,
                       ffi::Buffer<ffi::F32> qpos, ffi::Buffer<ffi::F32> qvel,
                       ffi::Buffer<ffi::F32> act, ffi::ResultBuffer<ffi::F32> time_out,
                       ffi::ResultBuffer<ffi::F32> qpos_out, ffi::ResultBuffer<ffi::F32> qvel_out,
                       ffi::ResultBuffer<ffi::F32> act_out, ffi::ResultBuffer<ffi::F32> sens_out,
                       ffi::ResultBuffer<ffi::F32> cfrc_out) {
  Batch b;
  ffi::Error err = Open(model_id, cfrc != 0, time, qpos, qvel, act, time_out, qpos_out, qvel_out, act_out,
                        sens_out, cfrc_out, &b);
  if (err.failure()) return err;
  ParallelFor(b.e, b.n, nullptr, [&](mjData* d, int64_t i) {
    Load(b, d, i);
    mju_zero(d->ctrl, b.m->nu);
    Store(b, d, i);
  });
  return ffi::Error::Success();
}

// Both handlers take the state before their call (time, qpos, qvel, act) and return it after it
// (time, qpos, qvel, act, sensors, cfrc_ext).
template <typename Binding>
auto StateArgs(Binding binding) {
  using In = ffi::Buffer<ffi::F32>;
  return std::move(binding).template Arg<In>().template Arg<In>().template Arg<In>().template Arg<In>();
}

template <typename Binding>
auto StateResults(Binding binding) {
  using Out = ffi::Buffer<ffi::F32>;
  return std::move(binding).template Ret<Out>().template Ret<Out>().template Ret<Out>().template Ret<Out>()
      .template Ret<Out>().template Ret<Out>();
}

}  // namespace

XLA_FFI_DEFINE_HANDLER_SYMBOL(HdtPhysicsStep, StepImpl,
                              StateResults(StateArgs(ffi::Ffi::Bind()
                                                         .Ctx<ffi::ThreadPool>()
                                                         .Attr<int64_t>("model_id")
                                                         .Attr<int64_t>("frame_skip")
                                                         .Attr<int64_t>("cfrc"))  // 1: also return cfrc_ext
                                               .Arg<ffi::Buffer<ffi::F32>>()  // ctrl
                                               .Arg<ffi::Buffer<ffi::F32>>()));  // active (1 = step, 0 = pass through)

XLA_FFI_DEFINE_HANDLER_SYMBOL(HdtPhysicsForward, ForwardImpl,
                              StateResults(StateArgs(ffi::Ffi::Bind().Attr<int64_t>("model_id").Attr<int64_t>("cfrc"))));

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
