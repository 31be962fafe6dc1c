// physclient for Python: pybind11 bindings of the client SDK (docs/PYTHON.md).
//
//   import physclient as pc
//   with pc.Client(domain=0) as c:
//       c.connect()
//       w = c.create_world("demo")
//       ids = w.spawn([pc.BodyDef(position=(0, 0, 2),
//                                 shapes=[pc.ShapeDef(pc.ShapeGeom.box((0.5, 0.5, 0.5)))])])
//       w.step(60)
//       print(w.query_state().bodies[0].position)
//
// Threads and the GIL. Every call that waits releases the GIL. Requests and wait_for_frame wait
// in slices of 100 ms, checking for signals between them (Ctrl-C interrupts a wait; the request
// itself is not cancelled); connect() and world_named() wait in one piece (the SDK's own waits,
// bounded by their timeouts). Subscription and event callbacks run on the SDK's
// thread and take the GIL for the call. A request of a client from inside one of that client's
// callbacks would wait for a reply that the same thread has to take: it raises RuntimeError
// instead of deadlocking. The SDK holds callbacks weakly; the Python objects that hold them
// (a Subscription, a Client's connection for on_event) let go of them with the GIL held: once
// close() or on_event() has returned, the callback is not called again (Subscription.close()
// also waits for a call already running, as the C++ Subscription does; after on_event() one
// may still be finishing). A Client is destroyed (its thread joined)
// with the GIL released, so that a callback waiting for the GIL can finish. Clients still open
// when the interpreter exits are closed by an atexit hook, before Python finalizes.
//
// Vectors are tuples (x, y, z); rotations are unit quaternions as the SDK stores them,
// (x, y, z, w). Body and joint ids are the SDK's packed 64-bit ids (ints).
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>

#include <Python.h>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <future>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <system_error>
#include <thread>
#include <type_traits>
#include <utility>
#include <vector>

#include "phys/client/client.h"
#include "phys/client/error.h"

namespace py = pybind11;
namespace pc = phys::client;

// ---------------------------------------------------------------------------------------------
// Vec3 and Quat as Python sequences of floats (tuples when returned).

namespace pybind11::detail {

inline bool loadFloats(handle src, float* out, size_t n) {
  if (!src || !PySequence_Check(src.ptr()) || PyUnicode_Check(src.ptr()) ||
      PyBytes_Check(src.ptr()))
    return false;
  const Py_ssize_t size = PySequence_Size(src.ptr());
  if (size != Py_ssize_t(n)) {
    if (size < 0) PyErr_Clear();
    return false;
  }
  for (size_t i = 0; i < n; ++i) {
    object item = reinterpret_steal<object>(PySequence_GetItem(src.ptr(), Py_ssize_t(i)));
    if (!item) {
      PyErr_Clear();
      return false;
    }
    const double d = PyFloat_AsDouble(item.ptr());
    if (d == -1.0 && PyErr_Occurred()) {
      PyErr_Clear();
      return false;
    }
    out[i] = float(d);
  }
  return true;
}

template <>
struct type_caster<phys::Vec3> {
  PYBIND11_TYPE_CASTER(phys::Vec3, const_name("tuple[float, float, float]"));
  bool load(handle src, bool) {
    float v[3];
    if (!loadFloats(src, v, 3)) return false;
    value = {v[0], v[1], v[2]};
    return true;
  }
  static handle cast(const phys::Vec3& v, return_value_policy, handle) {
    return make_tuple(v.x, v.y, v.z).release();
  }
};

template <>
struct type_caster<phys::Quat> {
  PYBIND11_TYPE_CASTER(phys::Quat, const_name("tuple[float, float, float, float]"));
  bool load(handle src, bool) {
    float v[4];
    if (!loadFloats(src, v, 4)) return false;
    value = phys::Quat{v[0], v[1], v[2], v[3]};
    return true;
  }
  static handle cast(const phys::Quat& q, return_value_policy, handle) {
    return make_tuple(q.x, q.y, q.z, q.w).release();
  }
};

// The module's enums (py::enum_: BodyType, JointType, PointFrame, ...) as arguments and
// attributes: a member (BodyType.Static) or its name as a string in any case
// (BodyDef(type="static"), apply_force(..., frame="world")). Anything else raises one
// sentence naming the valid values: ValueError for an unknown name, TypeError for another
// type, instead of pybind11's listing of the function's signatures. The error is thrown from
// load(), which pybind11 lets through as the call's exception; it is only thrown in the
// converting pass (the functions that take these enums have no overloads to try next).
std::string lowerAscii(std::string s) {
  for (char& c : s)
    if (c >= 'A' && c <= 'Z') c = char(c - 'A' + 'a');
  return s;
}

template <class E>
struct named_enum_caster : type_caster_base<E> {
  E named{};
  bool load(handle src, bool convert) {
    if (type_caster_base<E>::load(src, convert)) return true;
    if (!convert || !src) return false;
    const type_info* ti = get_type_info(typeid(E));
    if (!ti) return false;  // not bound (yet): as pybind11 would
    const handle type(reinterpret_cast<PyObject*>(ti->type));
    const std::string typeName = type.attr("__name__").cast<std::string>();
    const dict members = type.attr("__members__");
    std::string names;
    size_t i = 0;
    for (auto item : members) {
      names += (i == 0 ? "" : i + 1 == members.size() ? " or " : ", ");
      names += typeName + "." + std::string(str(item.first));
      ++i;
    }
    if (PyUnicode_Check(src.ptr())) {
      const std::string given = src.cast<std::string>();
      for (auto item : members) {
        if (lowerAscii(std::string(str(item.first))) == lowerAscii(given)) {
          named = item.second.template cast<E>();
          this->value = &named;
          return true;
        }
      }
      throw value_error("physclient: '" + given + "' is not a " + typeName + ": use " + names +
                        " (or the name as a string)");
    }
    throw type_error("physclient: expected a " + typeName + " (" + names +
                     ", or the name as a string), not " +
                     std::string(str(type::handle_of(src).attr("__name__"))));
  }
};

template <>
struct type_caster<phys::BodyType> : named_enum_caster<phys::BodyType> {};
template <>
struct type_caster<phys::JointType> : named_enum_caster<phys::JointType> {};
template <>
struct type_caster<phys::ShapeType> : named_enum_caster<phys::ShapeType> {};
template <>
struct type_caster<phys::client::PointFrame> : named_enum_caster<phys::client::PointFrame> {};

}  // namespace pybind11::detail

namespace {

// ---------------------------------------------------------------------------------------------
// Exceptions: physclient.Error and a subclass per ErrorCode.

PyObject* gError = nullptr;  // physclient.Error (a new reference kept for the process)
struct ErrorClass {
  pc::ErrorCode code;
  const char* name;
  PyObject* extraBase;  // a builtin exception it also derives from, or null
  PyObject* cls = nullptr;
};
std::vector<ErrorClass>& errorClasses() {
  static auto* classes = new std::vector<ErrorClass>;  // leaked: lives until the process ends
  return *classes;
}

/// The exception object for e: an instance of its code's class, with code, message and
/// from_server (raised by raiseError, or set on an asyncio.Future).
py::object errorObject(const pc::Error& e) {
  PyObject* cls = gError;
  for (const ErrorClass& c : errorClasses())
    if (c.code == e.code()) cls = c.cls;
  py::object type = py::reinterpret_borrow<py::object>(cls);
  py::object exc = type(py::str(e.what()));
  exc.attr("code") = py::cast(e.code());
  exc.attr("message") = py::str(e.message());
  exc.attr("from_server") = py::bool_(e.fromServer());
  exc.attr("retry_after_ms") = py::int_(e.retryAfterMs());
  return exc;
}

void raiseError(const pc::Error& e) {
  py::object exc = errorObject(e);
  PyErr_SetObject(reinterpret_cast<PyObject*>(Py_TYPE(exc.ptr())), exc.ptr());
}

// ---------------------------------------------------------------------------------------------
// Clients, leases and the interpreter's exit.

/// Set by the atexit hook: callbacks stop calling into Python, callback holders no longer
/// touch their objects (the interpreter is going away).
std::atomic<bool> gExiting{false};

struct PyCallback;

/// The C++ client of a physclient.Client, shared by the Client and its World and
/// Subscription objects: the connection lasts while one of them does, or until close(). Null
/// once closed. Calls hold a copy of the pointer (a lease) while they run, so that close()
/// from another thread never pulls the client from under them: the last holder destroys it
/// (deleteClient, the pointer's deleter).
struct ClientBox {
  /// Serializes on_event() and close(): the SDK's event function and the callback it refers
  /// to change together. Taken before m.
  std::mutex eventMutex;
  /// The event callback (on_event): the only strong reference; the SDK's function holds a
  /// weak one, so that the SDK never releases the last reference under its own lock.
  std::shared_ptr<PyCallback> eventCallback;
  std::mutex m;
  std::shared_ptr<pc::Client> client;
  ClientBox() = default;
  ClientBox(const ClientBox&) = delete;
  ClientBox& operator=(const ClientBox&) = delete;
};
using BoxPtr = std::shared_ptr<ClientBox>;

std::mutex& registryMutex() {
  static auto* m = new std::mutex;
  return *m;
}
std::vector<std::weak_ptr<ClientBox>>& registry() {
  static auto* r = new std::vector<std::weak_ptr<ClientBox>>;
  return *r;
}

/// The client whose callback this thread is running (SDK threads only), if any. Python code
/// runs on an SDK thread only inside invokeCallback (which sets this), and so does every
/// release of a Python reference there (the SDK holds callbacks weakly).
thread_local const ClientBox* tlCallbackOf = nullptr;

/// Runs f with the GIL released where this thread holds it (f may join a thread that waits
/// for the GIL), as it is otherwise.
template <class F>
void withoutGil(F&& f) {
  if (Py_IsInitialized() && PyGILState_Check()) {
    py::gil_scoped_release release;
    f();
  } else {
    f();
  }
}

/// The deleter of every pc::Client: runs once, on the thread that lets go of the last
/// reference (a decision no use_count() check can make without a race). The client is
/// destroyed (its thread joined) with the GIL released, so that a callback waiting for the
/// GIL can finish. On an SDK thread (in a callback: the thread that a client's destruction
/// may have to join) it goes to a thread of its own.
void deleteClient(pc::Client* c) {
  if (tlCallbackOf) {
    try {
      std::thread([c] { delete c; }).detach();
    } catch (const std::system_error&) {
      // No thread to be had: leaking the client is better than joining this thread itself.
    }
    return;
  }
  withoutGil([c] { delete c; });
}

struct Lease {
  std::shared_ptr<pc::Client> client;
  explicit Lease(const BoxPtr& box) {
    std::lock_guard<std::mutex> lk(box->m);
    client = box->client;
    if (!client) throw std::runtime_error("physclient: the client is closed");
  }
  Lease(const Lease&) = delete;
  Lease& operator=(const Lease&) = delete;
  pc::Client& operator*() const { return *client; }
  pc::Client* operator->() const { return client.get(); }
};

struct CallbackScope {
  const ClientBox* previous;
  explicit CallbackScope(const ClientBox* box) : previous(tlCallbackOf) { tlCallbackOf = box; }
  ~CallbackScope() { tlCallbackOf = previous; }
};

void checkNotInCallback(const BoxPtr& box) {
  if (tlCallbackOf == box.get())
    throw std::runtime_error(
        "physclient: a request of a client from its own subscription or event callback would "
        "wait for a reply that only this thread can take; make it from another thread");
}

/// A Python callable given as a callback: held strongly by its Python-side owner (the
/// Subscription, or the client's box for on_event) and weakly by the SDK's std::function, so
/// that its last reference goes with the GIL held on a Python thread (close(), on_event(),
/// the owner's collection) or inside invokeCallback, never under one of the SDK's locks (the
/// SDK destroys a replaced event function under the lock that latest_status() and the like
/// take with the GIL held). Released with the GIL held, whichever thread lets go of it last.
struct PyCallback {
  py::object fn;
  explicit PyCallback(py::object f) : fn(std::move(f)) {}
  PyCallback(const PyCallback&) = delete;
  PyCallback& operator=(const PyCallback&) = delete;
  ~PyCallback() {
    if (!fn) return;
    if (gExiting.load() || !Py_IsInitialized()) {
      fn.release();  // the interpreter is going away: leave it be
      return;
    }
    py::gil_scoped_acquire gil;
    fn = py::object();
  }
};

/// Calls cb(arg) on the SDK's thread with the GIL; an exception of the callback is reported as
/// unraisable (sys.unraisablehook), never thrown into the SDK. The weak reference is taken
/// under the GIL, as its owner drops it: once close() / on_event() has returned, no call
/// starts any more (after on_event(), one already running may still be finishing).
template <class T>
void invokeCallback(const std::weak_ptr<PyCallback>& weak, const ClientBox* box, const T& arg,
                    const char* what) {
  if (gExiting.load()) return;
  py::gil_scoped_acquire gil;
  if (gExiting.load()) return;
  CallbackScope scope(box);  // outlives cb: a last reference dropped here is in the scope
  const std::shared_ptr<PyCallback> cb = weak.lock();
  if (!cb) return;
  try {
    cb->fn(py::cast(arg, py::return_value_policy::copy));
  } catch (py::error_already_set& e) {
    e.discard_as_unraisable(what);
  } catch (const std::exception& e) {
    PyErr_SetString(PyExc_RuntimeError, e.what());
    PyErr_WriteUnraisable(cb->fn.ptr());
  }
}

/// Closes a client: its client (destroyed by the last lease, its thread joined) and its
/// event callback (released here, with the GIL held, after the client let go of it).
void closeBox(ClientBox& box) {
  std::shared_ptr<pc::Client> c;
  std::shared_ptr<PyCallback> events;
  {
    std::lock_guard<std::mutex> ev(box.eventMutex);
    std::lock_guard<std::mutex> lk(box.m);
    c.swap(box.client);
    events.swap(box.eventCallback);
  }
  c.reset();
  events.reset();
}

/// The longest timeout (24 days). The SDK adds a timeout to steady_clock::now() (int64
/// nanoseconds: an hour's timeout is fine, 1e10 s overflows and expires at once) and waits on
/// condition variables with it; 24 days keeps every such sum far from overflowing, and the
/// milliseconds below 2^31.
constexpr double kMaxTimeoutS = 24.0 * 24 * 3600;

/// Seconds -> milliseconds, rounded up; ValueError for a negative one or NaN, and longer
/// ones (inf too) are the longest (kMaxTimeoutS).
std::chrono::milliseconds toMs(double seconds) {
  if (!(seconds >= 0))
    throw py::value_error("physclient: a timeout is a number of seconds >= 0 (not NaN)");
  seconds = std::min(seconds, kMaxTimeoutS);
  return std::chrono::milliseconds(int64_t(std::ceil(seconds * 1000.0)));
}

pc::CallOptions callOptions(std::optional<double> timeout) {
  pc::CallOptions o;
  if (timeout) {
    o.timeout = toMs(*timeout);
    if (o.timeout.count() == 0) o.timeout = std::chrono::milliseconds(1);
  }
  return o;
}

constexpr std::chrono::milliseconds kSlice{100};

/// Waits for a future with the GIL released, a slice at a time, checking for signals between
/// slices (KeyboardInterrupt); then returns its value or throws its error.
template <class T>
T waitFuture(std::future<T> fut) {
  for (;;) {
    std::future_status st;
    {
      py::gil_scoped_release release;
      st = fut.wait_for(kSlice);
    }
    if (st == std::future_status::ready) break;
    if (PyErr_CheckSignals() != 0) throw py::error_already_set();
  }
  return fut.get();
}

/// A request: mk(client) sends it (GIL released) and returns its future; waited for as above
/// while a lease keeps the client.
template <class MakeFuture>
auto request(const BoxPtr& box, MakeFuture&& mk) {
  checkNotInCallback(box);
  Lease lease(box);
  auto fut = [&] {
    py::gil_scoped_release release;
    return mk(*lease);
  }();
  return waitFuture(std::move(fut));
}

/// A blocking SDK call that returns no future: run with the GIL released.
template <class F>
auto blocking(const BoxPtr& box, F&& f) {
  checkNotInCallback(box);
  Lease lease(box);
  py::gil_scoped_release release;
  return f(*lease);
}

/// A non-blocking SDK call (no wait on the SDK's thread).
template <class F>
auto quick(const BoxPtr& box, F&& f) {
  Lease lease(box);
  return f(*lease);
}

template <class T>
std::vector<T> oneOrMany(const py::object& o, const char* what) {
  if (py::isinstance<T>(o)) return {o.cast<T>()};
  try {
    return o.cast<std::vector<T>>();
  } catch (const py::cast_error&) {
    throw py::type_error(std::string("physclient: expected a ") + what + " or a list of them");
  }
}

std::vector<uint64_t> idList(const py::object& o) {
  if (o.is_none()) return {};
  if (py::isinstance<py::int_>(o)) return {o.cast<uint64_t>()};
  return o.cast<std::vector<uint64_t>>();
}

/// A buffer's bytes in C order. Any buffer will do: a strided one (memoryview(b)[::-1], a
/// numpy slice) is copied element by element (PyBuffer_ToContiguous), not read as len bytes
/// from its pointer (they are not its bytes, or not even inside it).
std::vector<uint8_t> bytesOf(const py::buffer& b) {
  Py_buffer view;
  if (PyObject_GetBuffer(b.ptr(), &view, PyBUF_FULL_RO) != 0) throw py::error_already_set();
  std::vector<uint8_t> out(size_t(view.len));
  const int rc = view.len > 0 ? PyBuffer_ToContiguous(out.data(), &view, view.len, 'C') : 0;
  PyBuffer_Release(&view);
  if (rc != 0) throw py::error_already_set();
  return out;
}

/// A def struct made from keyword arguments: its default, then each keyword set as the
/// attribute of that name (unknown names raise TypeError).
template <class T>
T fromKwargs(T value, const py::kwargs& kw, const char* type) {
  if (kw.empty()) return value;
  py::object o = py::cast(std::move(value));
  for (auto item : kw) {
    const std::string key = py::str(item.first);
    if (key.empty() || key[0] == '_' || !py::hasattr(py::type::of(o), key.c_str()))
      throw py::type_error(std::string(type) + "() got an unexpected keyword argument '" + key +
                           "'");
    py::setattr(o, item.first, item.second);
  }
  return o.template cast<T>();
}

template <class T>
std::string reprOf(const T& v) {
  return std::string(py::repr(py::cast(v)));
}

// ---------------------------------------------------------------------------------------------
// A state frame's bodies as one buffer: rows of 13 float32 (position xyz, rotation xyzw,
// linear velocity xyz, angular velocity xyz), for memoryview / numpy.asarray.

struct BodyArray {
  std::vector<float> data;
  size_t rows = 0;
  static constexpr size_t kColumns = 13;
  explicit BodyArray(const std::vector<pc::BodyState>& bodies) : rows(bodies.size()) {
    data.reserve(rows * kColumns);
    for (const pc::BodyState& b : bodies) {
      const float row[kColumns] = {b.position.x,        b.position.y,        b.position.z,
                                   b.rotation.x,        b.rotation.y,        b.rotation.z,
                                   b.rotation.w,        b.linearVelocity.x,  b.linearVelocity.y,
                                   b.linearVelocity.z,  b.angularVelocity.x, b.angularVelocity.y,
                                   b.angularVelocity.z};
      data.insert(data.end(), row, row + kColumns);
    }
  }
};

// ---------------------------------------------------------------------------------------------
// Solver overrides from keyword arguments.

/// An enum setting by its C++ enumerator's name (phys/defs/solver_settings.h's tables).
template <class E>
E enumByName(const py::handle& v, const char* what) {
  const std::string s = py::str(v);
  for (const phys::SettingName<E>& n : phys::settingNames(E{}))
    if (s == n.name) return n.value;
  std::string all;
  for (const phys::SettingName<E>& n : phys::settingNames(E{}))
    all += std::string(all.empty() ? "" : ", ") + n.name;
  throw py::value_error(std::string("physclient: ") + what + " is one of " + all);
}

/// A keyword's value as solver setting T.
template <class T>
T settingValue(const py::handle& v, const char* what) {
  if constexpr (std::is_enum_v<T>)
    return enumByName<T>(v, what);
  else
    return v.cast<T>();
}

/// A keyword of set_world (for set_solver's error: "set_solver(gravity=...)").
bool isWorldSetting(const std::string& k) {
#define PHYS_WORLD_NAME(type, member, path, name) #name,
  for (const char* n : {PHYS_WORLD_FIELDS(PHYS_WORLD_NAME)})
    if (k == n) return true;
#undef PHYS_WORLD_NAME
  return false;
}

pc::SolverOverrides solverOverrides(const py::kwargs& kw) {
  pc::SolverOverrides o;
  for (auto item : kw) {
    const std::string k = py::str(item.first);
    const py::handle v = item.second;
    // The keywords are the wire's names (PHYS_SOLVER_FIELDS).
#define PHYS_OVERRIDE(type, member, name, ...)                         \
  if (k == #name) {                                                    \
    o.member = settingValue<decltype(o.member)::value_type>(v, #name); \
    continue;                                                          \
  }
    PHYS_SOLVER_FIELDS(PHYS_OVERRIDE)
#undef PHYS_OVERRIDE
    if (isWorldSetting(k))
      throw py::type_error("set_solver() got an unexpected keyword argument '" + k + "': " + k +
                           " is a world setting, set with set_world(" + k + "=...)");
    throw py::type_error("set_solver() got an unexpected keyword argument '" + k + "'");
  }
  return o;
}

// ---------------------------------------------------------------------------------------------
// World settings from keyword arguments (set_world), and back (WorldSettings.solver).

pc::WorldOverrides worldOverrides(const py::kwargs& kw) {
  pc::WorldOverrides o;
  for (auto item : kw) {
    const std::string k = py::str(item.first);
    const py::handle v = item.second;
    if (v.is_none()) continue;  // as if not given: the world keeps its value
    // The keywords are the wire's names (PHYS_WORLD_FIELDS).
#define PHYS_SETTING(type, member, path, name) \
  if (k == #name) {                            \
    o.member = v.cast<type>();                 \
    continue;                                  \
  }
    PHYS_WORLD_FIELDS(PHYS_SETTING)
#undef PHYS_SETTING
    throw py::type_error("set_world() got an unexpected keyword argument '" + k +
                         "' (solver settings: set_solver)");
  }
  return o;
}

/// The solver's settings as set_solver's keywords: w.set_solver(**other.settings().solver).
py::dict solverDict(const phys::SolverSettings& s) {
  py::dict d;
  // An enum by its C++ enumerator's name, as set_solver takes it.
  auto value = [](auto v) {
    if constexpr (std::is_enum_v<decltype(v)>) {
      const auto* n = phys::settingName(v);
      return py::str(n ? n->name : "?");
    } else {
      return v;
    }
  };
#define PHYS_SETTING_ITEM(type, member, name, ...) d[#name] = value(s.member);
  PHYS_SOLVER_FIELDS(PHYS_SETTING_ITEM)
#undef PHYS_SETTING_ITEM
  return d;
}

// ---------------------------------------------------------------------------------------------
// Python-side objects.

class PySubscription {
 public:
  PySubscription(BoxPtr box, pc::Subscription sub, std::shared_ptr<PyCallback> cb)
      : box_(std::move(box)),
        world_(sub.world()),
        sub_(std::make_shared<pc::Subscription>(std::move(sub))),
        cb_(std::move(cb)) {}
  ~PySubscription() { close(); }
  PySubscription(const PySubscription&) = delete;
  PySubscription& operator=(const PySubscription&) = delete;

  /// Called with the GIL held (from Python, or the object's collection). Another thread may
  /// be in latest() or wait_for_frame() with the GIL released, using the subscription's state
  /// (the mutex and condition variable a waiter blocks on): each call holds a copy of sub_,
  /// so the state lives until the last of them returns, and the unsubscribing happens then,
  /// on the thread that drops the last copy (within a slice of wait_for_frame: 100 ms).
  void close() {
    std::shared_ptr<pc::Subscription> sub;
    {
      std::lock_guard<std::mutex> lk(m_);
      if (sub_) {
        closedFrames_ = sub_->framesReceived();
        closedSkipped_ = sub_->framesSkipped();
      }
      sub.swap(sub_);
    }
    // The callback's only strong reference, dropped with the GIL held: no call of it starts
    // after this (invokeCallback takes its reference under the GIL). One already running is
    // waited for by the SDK's reset below, with the GIL released so that it can finish
    // (unless another thread holds a copy of sub_: docs/PYTHON.md).
    cb_.reset();
    if (!sub) return;
    withoutGil([&sub] { sub.reset(); });
  }
  bool active() const {
    std::lock_guard<std::mutex> lk(m_);
    return bool(sub_);
  }
  uint32_t world() const { return world_; }
  std::optional<pc::StateFrame> latest() const {
    py::gil_scoped_release release;  // the copy below is dropped before the GIL comes back
    const std::shared_ptr<pc::Subscription> sub = current();
    if (!sub) return std::nullopt;
    return sub->latest();
  }
  std::optional<pc::StateFrame> waitForFrame(uint64_t afterTick, double timeoutS) {
    const auto end = std::chrono::steady_clock::now() + toMs(timeoutS);
    for (;;) {
      const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(
          end - std::chrono::steady_clock::now());
      std::optional<pc::StateFrame> f;
      {
        py::gil_scoped_release release;
        const std::shared_ptr<pc::Subscription> sub = current();
        if (!sub) return std::nullopt;  // closed: no frame will come
        f = sub->waitForFrame(afterTick, std::clamp(left, std::chrono::milliseconds(0), kSlice));
      }
      if (f || left <= kSlice) return f;
      if (PyErr_CheckSignals() != 0) throw py::error_already_set();
    }
  }
  // Under m_: close() cannot take the subscription away meanwhile (no copy to drop).
  uint64_t framesReceived() const {
    std::lock_guard<std::mutex> lk(m_);
    return sub_ ? sub_->framesReceived() : closedFrames_;
  }
  uint64_t framesSkipped() const {
    std::lock_guard<std::mutex> lk(m_);
    return sub_ ? sub_->framesSkipped() : closedSkipped_;
  }
  uint64_t staleChunks() const {
    std::lock_guard<std::mutex> lk(m_);
    return sub_ ? sub_->staleChunks() : 0;
  }

  /// `async for frame in subscription` (defineAsync): the tick of the frame it gave last
  /// (GIL held).
  struct AsyncIteration {
    bool started = false;
    uint64_t tick = 0;
  } aiter;

 private:
  friend struct FrameOp;  // waits on current() without the GIL, as waitForFrame() does
  std::shared_ptr<pc::Subscription> current() const {
    std::lock_guard<std::mutex> lk(m_);
    return sub_;
  }

  BoxPtr box_;  // keeps the connection
  uint32_t world_;
  mutable std::mutex m_;  // sub_ and the counts; never held while waiting for the GIL
  std::shared_ptr<pc::Subscription> sub_;          // null once closed
  uint64_t closedFrames_ = 0, closedSkipped_ = 0;  // the counts when closed
  std::shared_ptr<PyCallback> cb_;  // the callback's only strong reference (GIL held)
};

/// The SDK's function for a subscription callback: it refers to the callback weakly (the
/// Subscription holds it: *held).
std::function<void(const pc::StateFrame&)> frameCallback(const py::object& callback,
                                                         const BoxPtr& box,
                                                         std::shared_ptr<PyCallback>* held) {
  if (callback.is_none()) return {};
  if (!PyCallable_Check(callback.ptr()))
    throw py::type_error("physclient: callback must be callable (or None)");
  auto cb = std::make_shared<PyCallback>(callback);
  *held = cb;
  const ClientBox* raw = box.get();
  return [weak = std::weak_ptr<PyCallback>(cb), raw](const pc::StateFrame& f) {
    invokeCallback(weak, raw, f, "physclient subscription callback");
  };
}

class PyWorld {
 public:
  PyWorld(BoxPtr box, uint32_t id) : box_(std::move(box)), id_(id) {}
  uint32_t id() const { return id_; }
  const BoxPtr& box() const { return box_; }
  /// Made by create_world() (or create_world_async()): the end of a `with` block destroys it
  /// (defineWorldContext).
  bool created() const { return created_; }
  PyWorld& markCreated() {
    created_ = true;
    return *this;
  }

  template <class F>
  auto req(std::optional<double> timeout, F&& f) {
    const pc::CallOptions o = callOptions(timeout);
    return request(box_, [&](pc::Client& c) { return f(pc::WorldHandle(&c, id_), o); });
  }

  pc::WorldSummary info(std::optional<double> timeout) {
    auto worlds = request(box_, [&](pc::Client& c) { return c.listWorlds(callOptions(timeout)); });
    for (const pc::WorldSummary& w : worlds)
      if (w.world == id_) return w;
    throw pc::Error(pc::ErrorCode::NotFound, "no world " + std::to_string(id_));
  }

  PySubscription* subscribe(const py::object& callback, const py::object& bodies,
                            const py::object& region, std::optional<double> timeout) {
    checkNotInCallback(box_);
    std::shared_ptr<PyCallback> held;
    auto fn = frameCallback(callback, box_, &held);
    pc::Interest interest;
    interest.bodies = idList(bodies);
    if (!region.is_none()) {
      auto corners = region.cast<std::pair<phys::Vec3, phys::Vec3>>();
      interest.region = corners;
    }
    Lease lease(box_);
    pc::Subscription sub;
    {
      py::gil_scoped_release release;
      pc::WorldHandle w(&*lease, id_);
      sub = interest.all() ? w.subscribe(std::move(fn))
                           : w.subscribe(interest, std::move(fn), callOptions(timeout));
    }
    return new PySubscription(box_, std::move(sub), std::move(held));
  }

 private:
  BoxPtr box_;
  uint32_t id_;
  bool created_ = false;
};

class PyClient {
 public:
  PyClient(uint32_t domain, std::string name, std::optional<std::string> cycloneXml,
           uint64_t clientId, double connectTimeout, double requestTimeout, bool autoReconnect,
           std::optional<std::string> securityDir, std::optional<std::string> identity,
           std::optional<std::string> keyFile, bool retryBusy) {
    pc::ClientOptions o;
    o.domain = domain;
    o.name = std::move(name);
    o.cycloneXml = cycloneXml.value_or("");
    o.clientId = clientId;
    o.keyFile = keyFile.value_or("");
    o.connectTimeout = toMs(connectTimeout);
    o.requestTimeout = toMs(requestTimeout);
    o.autoReconnect = autoReconnect;
    o.retryBusy = retryBusy;
    if (securityDir || identity) {
      if (!securityDir || !identity)
        throw py::value_error("physclient: security_dir and identity go together");
      o.security = pc::SecurityFiles::fromDir(*securityDir, *identity);
    }
    box_ = std::make_shared<ClientBox>();
    {
      py::gil_scoped_release release;
      box_->client = std::shared_ptr<pc::Client>(new pc::Client(std::move(o)), deleteClient);
    }
    std::lock_guard<std::mutex> lk(registryMutex());
    auto& r = registry();
    r.erase(std::remove_if(r.begin(), r.end(), [](const auto& w) { return w.expired(); }),
            r.end());
    r.push_back(box_);
  }
  PyClient(const PyClient&) = delete;
  PyClient& operator=(const PyClient&) = delete;

  void close() { closeBox(*box_); }
  bool closed() const {
    std::lock_guard<std::mutex> lk(box_->m);
    return !box_->client;
  }
  const BoxPtr& box() const { return box_; }

  /// Subscription to events: fn on the SDK's thread for each. The box holds the callback;
  /// the SDK's function refers to it weakly, because Client::onEvent destroys the function
  /// it replaces under the SDK's info lock: had that been the last reference to the old
  /// callback, its release would wait for the GIL there, while a thread holding the GIL waits
  /// for that lock in latest_status(), recent_events() or server. The old callback goes here,
  /// with the GIL held, after the SDK's call returned.
  void onEvent(const py::object& callback) {
    std::shared_ptr<PyCallback> cb;
    std::function<void(const pc::Event&)> fn;
    if (!callback.is_none()) {
      if (!PyCallable_Check(callback.ptr()))
        throw py::type_error("physclient: callback must be callable (or None)");
      cb = std::make_shared<PyCallback>(callback);
      const ClientBox* raw = box_.get();
      fn = [weak = std::weak_ptr<PyCallback>(cb), raw](const pc::Event& e) {
        invokeCallback(weak, raw, e, "physclient event callback");
      };
    }
    checkNotInCallback(box_);
    {
      // The lock with the GIL released: its holders never wait for the GIL. Under it, the
      // client cannot be closed (close() takes it too): a callback is never left in a closed
      // box.
      py::gil_scoped_release release;
      std::lock_guard<std::mutex> lk(box_->eventMutex);
      Lease lease(box_);
      lease->onEvent(std::move(fn));
      cb.swap(box_->eventCallback);  // cb: the old callback
    }
  }  // cb released here, with the GIL held

 private:
  BoxPtr box_;
};

void closeAllClients() {
  std::vector<BoxPtr> boxes;
  {
    std::lock_guard<std::mutex> lk(registryMutex());
    for (auto& w : registry())
      if (auto b = w.lock()) boxes.push_back(std::move(b));
    registry().clear();
  }
  for (auto& b : boxes) closeBox(*b);
}

// ---------------------------------------------------------------------------------------------
// StateFrame as a sequence of its bodies (defineFrameSequence): len(frame), frame[i] (negative
// too) and frame[a:b] (a list), `for body in frame`, frame.get(id), `id in frame`. Each gives
// copies of BodyState, as frame.bodies does, but without copying the whole list first:
// frame[i] and frame.get(id) cost one body. frame.array() stays the fast path for every body
// at once.

/// The position of body `id` in f.bodies, or -1. A subscription's frames and a query_state
/// answer for every body are in index order (the id's low 32 bits: client.h, PROTOCOL.md), so a
/// binary search by index finds a body in O(log n); an answer for given ids is in their
/// order, so a miss falls back to a scan (an absent id costs one).
ptrdiff_t bodyPosition(const pc::StateFrame& f, uint64_t id) {
  const std::vector<pc::BodyState>& b = f.bodies;
  const uint32_t index = uint32_t(id);
  size_t lo = 0, hi = b.size();
  while (lo < hi) {
    const size_t mid = lo + (hi - lo) / 2;
    if (uint32_t(b[mid].id) < index)
      lo = mid + 1;
    else
      hi = mid;
  }
  if (lo < b.size() && b[lo].id == id) return ptrdiff_t(lo);
  for (size_t i = 0; i < b.size(); ++i)
    if (b[i].id == id) return ptrdiff_t(i);
  return -1;
}

/// An int as a body id; nullopt for one no body has (negative, past 64 bits). TypeError for
/// anything but an int.
std::optional<uint64_t> bodyIdOf(const py::object& id) {
  if (!PyLong_Check(id.ptr()))
    throw py::type_error("physclient: a body id is an int, not " +
                         std::string(py::str(py::type::handle_of(id).attr("__name__"))));
  const uint64_t v = PyLong_AsUnsignedLongLong(id.ptr());
  if (PyErr_Occurred()) {
    PyErr_Clear();
    return std::nullopt;
  }
  return v;
}

py::object bodyCopy(const pc::BodyState& b) { return py::cast(b, py::return_value_policy::copy); }

void defineFrameSequence(py::module_& m) {
  auto frame = py::reinterpret_borrow<py::class_<pc::StateFrame>>(m.attr("StateFrame"));
  frame
      .def(
          "__getitem__",
          [](const pc::StateFrame& f, const py::object& key) -> py::object {
            const auto n = py::ssize_t(f.bodies.size());
            if (PySlice_Check(key.ptr())) {
              py::ssize_t start = 0, stop = 0, step = 0, count = 0;
              if (!key.cast<py::slice>().compute(n, &start, &stop, &step, &count))
                throw py::error_already_set();
              py::list out(count);
              for (py::ssize_t i = 0; i < count; ++i)
                out[size_t(i)] = bodyCopy(f.bodies[size_t(start + i * step)]);
              return out;
            }
            if (!PyIndex_Check(key.ptr()))
              throw py::type_error(
                  "physclient: a StateFrame is indexed by position (an int) or a slice, not " +
                  std::string(py::str(py::type::handle_of(key).attr("__name__"))) +
                  "; frame.get(id) looks a body up by its id");
            py::ssize_t i = PyNumber_AsSsize_t(key.ptr(), nullptr);  // clipped when huge
            if (i == -1 && PyErr_Occurred()) throw py::error_already_set();
            if (i < 0) i += n;
            if (i < 0 || i >= n)
              throw py::index_error("physclient: StateFrame index " +
                                    std::string(py::str(key)) + " out of range (" +
                                    std::to_string(n) +
                                    " bodies); frame.get(id) looks a body up by its id");
            return bodyCopy(f.bodies[size_t(i)]);
          },
          py::arg("index"),
          "frame[i]: the i-th body (BodyState; negative from the end); frame[a:b]: a list.")
      .def(
          "__iter__",
          [](const pc::StateFrame& f) {
            return py::make_iterator<py::return_value_policy::copy>(f.bodies.begin(),
                                                                    f.bodies.end());
          },
          py::keep_alive<0, 1>(), "The bodies in order (BodyState, a copy each).")
      .def(
          "get",
          [](const pc::StateFrame& f, const py::object& id, const py::object& dflt) -> py::object {
            const std::optional<uint64_t> v = bodyIdOf(id);
            const ptrdiff_t i = v ? bodyPosition(f, *v) : -1;
            return i < 0 ? dflt : bodyCopy(f.bodies[size_t(i)]);
          },
          py::arg("id"), py::arg("default") = py::none(),
          "The state of body `id` (BodyState), or default (None) when the frame lacks it.")
      .def(
          "__contains__",
          [](const pc::StateFrame& f, const py::object& what) {
            if (py::isinstance<pc::BodyState>(what))
              return bodyPosition(f, what.cast<const pc::BodyState&>().id) >= 0;
            if (!PyLong_Check(what.ptr())) return false;
            const std::optional<uint64_t> id = bodyIdOf(what);
            return id && bodyPosition(f, *id) >= 0;
          },
          "`id in frame`: whether the frame holds that body (an id, or a BodyState's id).")
      .def_property_readonly(
          "stamp",
          [](const pc::StateFrame& f) -> py::object {
            if (f.stampNs == 0) return py::none();
            return py::float_(double(f.stampNs) * 1e-9);
          },
          "When the server read these states, in seconds since the Unix epoch (as time.time());\n"
          "None when the server sent no time (stamp_ns 0). time.time() - frame.stamp is the\n"
          "frame's age (same host or synced clocks).");
}

// ---------------------------------------------------------------------------------------------
// asyncio (docs/PYTHON.md "asyncio"): World.<request>_async, Client.<request>_async,
// Subscription.wait_for_frame_async and `async for frame in subscription`.
//
// An *_async call sends its request at once, as the blocking call does, and returns an
// asyncio.Future of the running loop; nothing waits in the call. The SDK's std::future goes to
// the Completer: one thread for the process, which waits on the oldest pending operation for
// up to kAsyncSlice with the GIL released, then checks the others (wait_for(0): an atomic load
// each), and when some are done takes the GIL once for all of them, turns each outcome into a
// result or an exception object (the typed physclient.Error) and hands it to its loop
// (loop.call_soon_threadsafe), where the asyncio.Future is settled unless it was cancelled
// meanwhile. So the event loop never blocks, no thread holds the GIL while waiting, and any
// number of requests may be in flight on one thread (each is an entry in a list). std::future
// has no completion callback, hence waiting on the oldest: replies mostly come in order, so
// the Completer wakes as the oldest one's arrives; one that overtakes it (a quick request
// behind a long step of another world) is seen within a slice.
//
// Every SDK future is resolved in the end, by the reply, the request's timeout or the client's
// destruction (Disconnected), so no entry waits forever; a frame wait ends at its timeout,
// when its subscription closes, or when its asyncio.Future is cancelled. A pending entry keeps
// its connection (as a World does) until it is settled; close() fails it at once. At exit the
// Completer is stopped after the clients are closed (the atexit hook).

constexpr std::chrono::milliseconds kAsyncSlice{1};

/// Settles an asyncio.Future on its loop: future.set_result(result), or set_exception(error)
/// when error is not None; nothing when it is done already (cancelled). Made at import.
py::object* gSettle = nullptr;

struct AsyncOp {
  BoxPtr box;         // keeps the connection while pending (null for none)
  py::object loop;    // the caller's running loop
  py::object future;  // its asyncio.Future
  /// A NotFound failure is a result of None (the end of `async with world`: gone already).
  bool notFoundIsNone = false;
  AsyncOp() = default;
  AsyncOp(const AsyncOp&) = delete;
  AsyncOp& operator=(const AsyncOp&) = delete;
  virtual ~AsyncOp() = default;  // with the GIL held (py::object members), or leaked at exit
  /// Waits up to `slice` for the outcome, without the GIL; true once it is known.
  virtual bool wait(std::chrono::milliseconds slice) = 0;
  /// The outcome (GIL held): the result, or *error set to an exception object; a failure may
  /// also be thrown (pc::Error, py::error_already_set, std::exception).
  virtual py::object result(py::object* error) = 0;
};

template <class T>
struct FutureOp : AsyncOp {
  std::future<T> fut;
  std::function<py::object(T)> convert;  // GIL held
  bool wait(std::chrono::milliseconds slice) override {
    return fut.wait_for(slice) == std::future_status::ready;
  }
  py::object result(py::object*) override { return convert(fut.get()); }
};

/// A frame of a subscription: wait_for_frame_async (the first with tick > after, or None at
/// the deadline or when the subscription is closed) and `async for` (StopAsyncIteration when
/// closed; no deadline; the first: the newest frame received already, if any).
struct FrameOp : AsyncOp {
  py::object subObject;  // keeps the PySubscription (sub) alive
  PySubscription* sub = nullptr;
  uint64_t after = 0;
  bool anyFirst = false;  // async for's first frame: the newest there is, whatever its tick
  bool iteration = false;
  std::chrono::steady_clock::time_point deadline;
  std::shared_ptr<std::atomic<bool>> cancelled = std::make_shared<std::atomic<bool>>(false);
  std::optional<pc::StateFrame> frame;
  bool closed = false;

  bool wait(std::chrono::milliseconds slice) override {
    // Once known, known: the Completer asks the oldest operation twice in a turn, and a
    // second waitForFrame() would not hand out the frame the first one took (it counts as
    // given), so the first frame of a paused world was lost and the wait ran to its deadline.
    if (frame || closed || cancelled->load()) return true;
    const std::shared_ptr<pc::Subscription> s = sub->current();
    if (!s) {
      closed = true;
      return true;
    }
    if (anyFirst && (frame = s->latest())) return true;
    const auto now = std::chrono::steady_clock::now();
    if (now >= deadline) return true;
    const auto left = std::chrono::duration_cast<std::chrono::milliseconds>(deadline - now);
    frame = s->waitForFrame(after, std::min(slice, left));
    return frame || std::chrono::steady_clock::now() >= deadline;
  }
  py::object result(py::object* error) override {
    if (frame) {
      if (iteration) sub->aiter = {true, frame->tick};
      return py::cast(std::move(*frame));
    }
    if (iteration && closed)
      *error = py::reinterpret_steal<py::object>(PyObject_CallNoArgs(PyExc_StopAsyncIteration));
    return py::none();
  }
};

class Completer {
 public:
  /// Queues op (sent already); the thread starts with the first.
  void add(std::unique_ptr<AsyncOp> op) {
    std::lock_guard<std::mutex> lk(m_);
    if (stopped_) throw std::runtime_error("physclient: the interpreter is exiting");
    if (!thread_.joinable()) thread_ = std::thread([this] { run(); });
    incoming_.push_back(std::move(op));
    cv_.notify_one();
  }
  /// At exit, after the clients were closed (GIL released by the caller): what is still
  /// pending is dropped without touching Python.
  void stop() {
    {
      std::lock_guard<std::mutex> lk(m_);
      stopped_ = true;
      cv_.notify_one();
    }
    if (thread_.joinable()) thread_.join();
  }

 private:
  void run() {
    std::vector<std::unique_ptr<AsyncOp>> waiting, done;
    for (;;) {
      {
        std::unique_lock<std::mutex> lk(m_);
        cv_.wait(lk, [&] { return stopped_ || !incoming_.empty() || !waiting.empty(); });
        for (auto& op : incoming_) waiting.push_back(std::move(op));
        incoming_.clear();
        if (stopped_) break;
      }
      waiting.front()->wait(kAsyncSlice);
      size_t kept = 0;
      for (size_t i = 0; i < waiting.size(); ++i) {
        if (waiting[i]->wait(std::chrono::milliseconds(0)))
          done.push_back(std::move(waiting[i]));
        else if (kept++ != i)
          waiting[kept - 1] = std::move(waiting[i]);
      }
      waiting.resize(kept);
      if (!done.empty()) settleAll(done);
    }
    forget(waiting);
  }

  static void settleAll(std::vector<std::unique_ptr<AsyncOp>>& done) {
    if (gExiting.load() || !Py_IsInitialized()) {
      forget(done);
      return;
    }
    py::gil_scoped_acquire gil;
    for (auto& op : done) {
      if (!gExiting.load()) settle(*op);
      op.reset();  // its Python references, with the GIL (a last BoxPtr lets go of it too)
    }
    done.clear();
  }

  static void settle(AsyncOp& op) {
    py::object result = py::none(), error = py::none();
    try {
      result = op.result(&error);
    } catch (const pc::Error& e) {
      if (op.notFoundIsNone && e.code() == pc::ErrorCode::NotFound)
        result = py::none();
      else
        error = errorObject(e);
    } catch (py::error_already_set& e) {
      e.restore();
      PyObject *type = nullptr, *value = nullptr, *trace = nullptr;
      PyErr_Fetch(&type, &value, &trace);
      PyErr_NormalizeException(&type, &value, &trace);
      if (value && trace) PyException_SetTraceback(value, trace);
      Py_XDECREF(type);
      Py_XDECREF(trace);
      error = value ? py::reinterpret_steal<py::object>(value) : py::none();
    } catch (const std::exception& e) {
      error = py::reinterpret_borrow<py::object>(PyExc_RuntimeError)(e.what());
    }
    try {
      op.loop.attr("call_soon_threadsafe")(*gSettle, op.future, result, error);
    } catch (py::error_already_set&) {
      // The loop is closed: nobody can await the future any more.
    }
  }

  /// Drops ops without Python (at exit): their Python references are left be.
  static void forget(std::vector<std::unique_ptr<AsyncOp>>& ops) {
    for (auto& op : ops) {
      op->loop.release();
      op->future.release();
      if (auto* f = dynamic_cast<FrameOp*>(op.get())) f->subObject.release();
      op.reset();
    }
    ops.clear();
  }

  std::mutex m_;
  std::condition_variable cv_;
  std::vector<std::unique_ptr<AsyncOp>> incoming_;
  bool stopped_ = false;
  std::thread thread_;
};

Completer& completer() {
  static auto* c = new Completer;  // leaked: stopped by the atexit hook, never destroyed
  return *c;
}

/// The running loop (RuntimeError outside one: asyncio.get_running_loop) and a new future.
std::pair<py::object, py::object> loopAndFuture() {
  py::object loop = py::module_::import("asyncio").attr("get_running_loop")();
  py::object future = loop.attr("create_future")();
  return {std::move(loop), std::move(future)};
}

template <class F>
struct FutureValue;
template <class T>
struct FutureValue<std::future<T>> {
  using type = T;
};

struct CastResult {
  template <class T>
  py::object operator()(T&& v) const {
    return py::cast(std::forward<T>(v));
  }
};

/// Sends a request as request() does (mk(client) with the GIL released) and returns an
/// asyncio.Future that the Completer settles with convert(value) or the typed error.
template <class MakeFuture, class Convert = CastResult>
py::object submitAsync(const BoxPtr& box, MakeFuture&& mk, Convert convert = {},
                       bool notFoundIsNone = false) {
  auto [loop, future] = loopAndFuture();
  Lease lease(box);
  auto fut = [&] {
    py::gil_scoped_release release;
    return mk(*lease);
  }();
  using T = typename FutureValue<decltype(fut)>::type;
  auto op = std::make_unique<FutureOp<T>>();
  op->box = box;
  op->loop = loop;
  op->future = future;
  op->notFoundIsNone = notFoundIsNone;
  op->fut = std::move(fut);
  op->convert = std::move(convert);
  completer().add(std::move(op));
  return future;
}

/// A World's request, as PyWorld::req sends it.
template <class F, class Convert = CastResult>
py::object worldAsync(const PyWorld& w, std::optional<double> timeout, F&& f,
                      Convert convert = {}, bool notFoundIsNone = false) {
  const pc::CallOptions o = callOptions(timeout);
  const uint32_t id = w.id();
  return submitAsync(
      w.box(), [&](pc::Client& c) { return f(pc::WorldHandle(&c, id), o); }, std::move(convert),
      notFoundIsNone);
}

/// A frame wait of a subscription (see FrameOp).
py::object frameAsync(py::object self, uint64_t after, std::optional<double> timeoutS,
                      bool iteration) {
  auto [loop, future] = loopAndFuture();
  auto op = std::make_unique<FrameOp>();
  op->sub = &self.cast<PySubscription&>();
  op->after = after;
  op->iteration = iteration;
  op->anyFirst = iteration && !op->sub->aiter.started;
  op->deadline = timeoutS ? std::chrono::steady_clock::now() + toMs(*timeoutS)
                          : std::chrono::steady_clock::time_point::max();
  // A cancelled wait (asyncio.wait_for, a cancelled task) leaves the Completer at once.
  future.attr("add_done_callback")(py::cpp_function(
      [flag = op->cancelled](const py::object&) { flag->store(true); }));
  op->subObject = std::move(self);
  op->loop = loop;
  op->future = future;
  completer().add(std::move(op));
  return future;
}

void defineAsync(py::module_& m) {
  using OptS = std::optional<double>;
  const auto T = py::arg("timeout") = py::none();
  gSettle = new py::object(py::cpp_function(
      [](const py::object& future, const py::object& result, const py::object& error) {
        if (future.attr("done")().cast<bool>()) return;  // cancelled meanwhile
        if (error.is_none())
          future.attr("set_result")(result);
        else
          future.attr("set_exception")(error);
      }));

  auto world = py::reinterpret_borrow<py::class_<PyWorld>>(m.attr("World"));
  using H = pc::WorldHandle;
  using O = pc::CallOptions;
  world
      .def(
          "info_async",
          [](PyWorld& w, OptS t) {
            const uint32_t id = w.id();
            const pc::CallOptions o = callOptions(t);
            return submitAsync(
                w.box(), [&](pc::Client& c) { return c.listWorlds(o); },
                [id](std::vector<pc::WorldSummary> all) -> py::object {
                  for (pc::WorldSummary& s : all)
                    if (s.world == id) return py::cast(std::move(s));
                  throw pc::Error(pc::ErrorCode::NotFound, "no world " + std::to_string(id));
                });
          },
          py::kw_only(), T, "info() without blocking: an asyncio.Future of WorldSummary.")
      .def(
          "destroy_async",
          [](PyWorld& w, OptS t) {
            return worldAsync(w, t, [](H h, O o) { return h.destroy(o); });
          },
          py::kw_only(), T)
      .def(
          "reset_async",
          [](PyWorld& w, OptS t) { return worldAsync(w, t, [](H h, O o) { return h.reset(o); }); },
          py::kw_only(), T)
      .def(
          "load_scene_async",
          [](PyWorld& w, const std::string& name, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.loadScene(name, o); });
          },
          py::arg("name"), py::kw_only(), T)
      .def(
          "load_scene_json_async",
          [](PyWorld& w, const std::string& json, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.loadSceneJson(json, o); });
          },
          py::arg("json"), py::kw_only(), T)
      .def(
          "spawn_async",
          [](PyWorld& w, const py::object& bodies, OptS t) {
            auto defs = oneOrMany<phys::BodyDef>(bodies, "BodyDef");
            return worldAsync(w, t, [&](H h, O o) {
              return h.spawn(std::span<const phys::BodyDef>(defs), o);
            });
          },
          py::arg("bodies"), py::kw_only(), T)
      .def(
          "remove_bodies_async",
          [](PyWorld& w, const py::object& ids, OptS t) {
            auto v = idList(ids);
            return worldAsync(
                w, t, [&](H h, O o) { return h.removeBodies(std::span<const uint64_t>(v), o); });
          },
          py::arg("ids"), py::kw_only(), T)
      .def(
          "add_joints_async",
          [](PyWorld& w, const py::object& joints, OptS t) {
            auto defs = oneOrMany<phys::JointDef>(joints, "JointDef");
            return worldAsync(w, t, [&](H h, O o) {
              return h.addJoints(std::span<const phys::JointDef>(defs), o);
            });
          },
          py::arg("joints"), py::kw_only(), T)
      .def(
          "remove_joints_async",
          [](PyWorld& w, const py::object& ids, OptS t) {
            auto v = idList(ids);
            return worldAsync(
                w, t, [&](H h, O o) { return h.removeJoints(std::span<const uint64_t>(v), o); });
          },
          py::arg("ids"), py::kw_only(), T)
      .def(
          "set_pose_async",
          [](PyWorld& w, uint64_t body, phys::Vec3 p, phys::Quat q, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.setPose(body, p, q, o); });
          },
          py::arg("body"), py::arg("position"), py::arg("rotation") = phys::Quat{}, py::kw_only(),
          T)
      .def(
          "set_velocity_async",
          [](PyWorld& w, uint64_t body, phys::Vec3 lin, phys::Vec3 ang, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.setVelocity(body, lin, ang, o); });
          },
          py::arg("body"), py::arg("linear"), py::arg("angular") = phys::Vec3{}, py::kw_only(), T)
      .def(
          "apply_force_async",
          [](PyWorld& w, uint64_t body, phys::Vec3 f, phys::Vec3 point, pc::PointFrame frame,
             OptS t) {
            return worldAsync(
                w, t, [&](H h, O o) { return h.applyForce(body, f, point, frame, o); });
          },
          py::arg("body"), py::arg("force"), py::arg("point") = phys::Vec3{},
          py::arg("frame") = pc::PointFrame::CenterOfMass, py::kw_only(), T)
      .def(
          "apply_impulse_async",
          [](PyWorld& w, uint64_t body, phys::Vec3 j, phys::Vec3 point, pc::PointFrame frame,
             OptS t) {
            return worldAsync(
                w, t, [&](H h, O o) { return h.applyImpulse(body, j, point, frame, o); });
          },
          py::arg("body"), py::arg("impulse"), py::arg("point") = phys::Vec3{},
          py::arg("frame") = pc::PointFrame::CenterOfMass, py::kw_only(), T)
      .def(
          "apply_torque_async",
          [](PyWorld& w, uint64_t body, phys::Vec3 torque, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.applyTorque(body, torque, o); });
          },
          py::arg("body"), py::arg("torque"), py::kw_only(), T)
      .def(
          "set_material_async",
          [](PyWorld& w, const py::object& bodies, const phys::Material& mt, OptS t) {
            auto v = idList(bodies);
            return worldAsync(w, t, [&](H h, O o) {
              return h.setMaterial(std::span<const uint64_t>(v), mt, o);
            });
          },
          py::arg("bodies"), py::arg("material"), py::kw_only(), T);
}

/// defineAsync's second half: the rest of World's *_async methods.
void defineWorldAsyncMore(py::module_& m) {
  using OptS = std::optional<double>;
  const auto T = py::arg("timeout") = py::none();
  using H = pc::WorldHandle;
  using O = pc::CallOptions;
  auto world = py::reinterpret_borrow<py::class_<PyWorld>>(m.attr("World"));
  world
      .def(
          "set_solver_async",
          [](PyWorld& w, const std::string& preset, OptS t, const py::kwargs& kw) {
            const pc::SolverOverrides ov = solverOverrides(kw);
            return worldAsync(w, t, [&](H h, O o) { return h.setSolver(preset, ov, o); });
          },
          py::arg("preset") = "", py::kw_only(), T)
      .def(
          "set_world_async",
          [](PyWorld& w, OptS t, const py::kwargs& kw) {
            const pc::WorldOverrides ov = worldOverrides(kw);
            return worldAsync(w, t, [&](H h, O o) { return h.setWorld(ov, o); });
          },
          py::kw_only(), T)
      .def(
          "set_gravity_async",
          [](PyWorld& w, phys::Vec3 g, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.setGravity(g, o); });
          },
          py::arg("gravity"), py::kw_only(), T)
      .def(
          "settings_async",
          [](PyWorld& w, OptS t) {
            return worldAsync(w, t, [](H h, O o) { return h.settings(o); });
          },
          py::kw_only(), T)
      .def(
          "get_bodies_async",
          [](PyWorld& w, const py::object& ids, uint32_t first, uint32_t maxCount, OptS t) {
            auto v = idList(ids);
            return worldAsync(w, t, [&](H h, O o) {
              return h.getBodies(std::span<const uint64_t>(v), first, maxCount, o);
            });
          },
          py::arg("ids") = py::none(), py::arg("first") = 0, py::arg("max_count") = 0,
          py::kw_only(), T)
      .def(
          "get_joints_async",
          [](PyWorld& w, const py::object& ids, uint32_t first, uint32_t maxCount, OptS t) {
            auto v = idList(ids);
            return worldAsync(w, t, [&](H h, O o) {
              return h.getJoints(std::span<const uint64_t>(v), first, maxCount, o);
            });
          },
          py::arg("ids") = py::none(), py::arg("first") = 0, py::arg("max_count") = 0,
          py::kw_only(), T)
      .def(
          "all_bodies_async",
          [](PyWorld& w, OptS t) {
            return worldAsync(w, t, [](H h, O o) { return h.allBodies(o); });
          },
          py::kw_only(), T)
      .def(
          "all_joints_async",
          [](PyWorld& w, OptS t) {
            return worldAsync(w, t, [](H h, O o) { return h.allJoints(o); });
          },
          py::kw_only(), T)
      .def(
          "step_async",
          [](PyWorld& w, uint32_t n, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.step(n, o); });
          },
          py::arg("n") = 1, py::kw_only(), T,
          "step(n) without blocking: sends it now -> an asyncio.Future of its Ack.")
      .def(
          "run_async",
          [](PyWorld& w, float rate, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.run(rate, o); });
          },
          py::arg("rate_hz") = 60.0f, py::kw_only(), T)
      .def(
          "pause_async",
          [](PyWorld& w, OptS t) { return worldAsync(w, t, [](H h, O o) { return h.pause(o); }); },
          py::kw_only(), T)
      .def(
          "move_async",
          [](PyWorld& w, uint64_t daemon, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.move(daemon, o); });
          },
          py::arg("daemon"), py::kw_only(), T)
      .def(
          "set_access_async",
          [](PyWorld& w, const py::object& editors, bool shared, OptS t) {
            auto v = idList(editors);
            return worldAsync(w, t, [&](H h, O o) {
              return h.setAccess(std::span<const uint64_t>(v), shared, o);
            });
          },
          py::arg("editors") = py::list(), py::arg("shared") = false, py::kw_only(), T)
      .def(
          "query_state_async",
          [](PyWorld& w, const py::object& ids, uint32_t first, uint32_t maxCount, OptS t) {
            auto v = idList(ids);
            return worldAsync(w, t, [&](H h, O o) {
              return h.queryState(std::span<const uint64_t>(v), first, maxCount, o);
            });
          },
          py::arg("ids") = py::none(), py::arg("first") = 0, py::arg("max_count") = 0,
          py::kw_only(), T)
      .def(
          "save_snapshot_async",
          [](PyWorld& w, OptS t) {
            return worldAsync(
                w, t, [](H h, O o) { return h.saveSnapshot(o); },
                [](pc::Bytes b) -> py::object {
                  return py::bytes(reinterpret_cast<const char*>(b.data()), b.size());
                });
          },
          py::kw_only(), T)
      .def(
          "save_snapshot_file_async",
          [](PyWorld& w, const std::string& file, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.saveSnapshotFile(file, o); });
          },
          py::arg("file"), py::kw_only(), T)
      .def(
          "restore_snapshot_async",
          [](PyWorld& w, const py::buffer& data, OptS t) {
            const std::vector<uint8_t> bytes = bytesOf(data);
            return worldAsync(w, t, [&](H h, O o) {
              return h.restoreSnapshot(std::span<const uint8_t>(bytes), o);
            });
          },
          py::arg("snapshot"), py::kw_only(), T)
      .def(
          "restore_snapshot_file_async",
          [](PyWorld& w, const std::string& file, OptS t) {
            return worldAsync(w, t, [&](H h, O o) { return h.restoreSnapshotFile(file, o); });
          },
          py::arg("file"), py::kw_only(), T);

}

/// Client's and Subscription's asyncio methods (issue 40).
void defineClientAsync(py::module_& m) {
  using OptS = std::optional<double>;
  const auto T = py::arg("timeout") = py::none();
  auto client = py::reinterpret_borrow<py::class_<PyClient>>(m.attr("Client"));
  client
      .def(
          "connect_async",
          [](PyClient& c) {
            auto [loop, future] = loopAndFuture();
            // The SDK's connect() blocks (it waits for a daemon to match): it runs on a thread
            // of its own, which holds the client as a lease does.
            std::shared_ptr<pc::Client> held = Lease(c.box()).client;
            auto promise = std::make_shared<std::promise<pc::ServerInfo>>();
            auto op = std::make_unique<FutureOp<pc::ServerInfo>>();
            op->fut = promise->get_future();
            op->convert = CastResult{};
            op->box = c.box();
            op->loop = loop;
            op->future = future;
            try {
              std::thread([held, promise]() mutable {
                try {
                  promise->set_value(held->connect());
                } catch (...) {
                  promise->set_exception(std::current_exception());
                }
                held.reset();
              }).detach();
            } catch (const std::system_error& e) {
              throw std::runtime_error(std::string("physclient: no thread for connect: ") +
                                       e.what());
            }
            completer().add(std::move(op));
            return future;
          },
          "connect() without blocking: an asyncio.Future of ServerInfo.")
      .def(
          "hello_async",
          [](PyClient& c, OptS t) {
            const pc::CallOptions o = callOptions(t);
            return submitAsync(c.box(), [&](pc::Client& cl) { return cl.hello(o); });
          },
          py::kw_only(), T)
      .def(
          "create_world_async",
          [](PyClient& c, const std::string& name, const std::string& preset,
             std::optional<phys::Vec3> gravity, float timeStep, const std::string& backend,
             bool sleep, bool ephemeral, const py::object& editors, bool shared, uint64_t daemon,
             OptS t) {
            pc::CreateWorldArgs a;
            a.name = name;
            a.preset = preset;
            a.gravity = gravity;
            a.timeStep = timeStep;
            a.backend = backend;
            a.sleep = sleep;
            a.ephemeral = ephemeral;
            a.editors = idList(editors);
            a.shared = shared;
            pc::CallOptions o = callOptions(t);
            o.daemon = daemon;
            BoxPtr box = c.box();
            return submitAsync(
                box, [&](pc::Client& cl) { return cl.createWorld(a, o); },
                [box](pc::WorldHandle h) -> py::object {
                  return py::cast(PyWorld(box, h.id()).markCreated());
                });
          },
          py::arg("name"), py::arg("preset") = "", py::kw_only(), py::arg("gravity") = py::none(),
          py::arg("time_step") = 0.0f, py::arg("backend") = "", py::arg("sleep") = true,
          py::arg("ephemeral") = false, py::arg("editors") = py::list(), py::arg("shared") = false,
          py::arg("daemon") = 0, T,
          "create_world() without blocking: an asyncio.Future of the World.")
      .def(
          "list_worlds_async",
          [](PyClient& c, uint64_t daemon, OptS t) {
            pc::CallOptions o = callOptions(t);
            o.daemon = daemon;
            return submitAsync(c.box(), [&](pc::Client& cl) { return cl.listWorlds(o); });
          },
          py::kw_only(), py::arg("daemon") = 0, T)
      .def(
          "world_named_async",
          [](PyClient& c, const std::string& name, OptS t) {
            const pc::CallOptions o = callOptions(t);
            BoxPtr box = c.box();
            return submitAsync(
                box, [&](pc::Client& cl) { return cl.listWorlds(o); },
                [box, name](std::vector<pc::WorldSummary> all) -> py::object {
                  for (const pc::WorldSummary& s : all)
                    if (s.name == name) return py::cast(PyWorld(box, s.world));
                  throw pc::Error(pc::ErrorCode::NotFound, "no world named '" + name + "'");
                });
          },
          py::arg("name"), py::kw_only(), T);

  auto subscription = py::reinterpret_borrow<py::class_<PySubscription>>(m.attr("Subscription"));
  subscription
      .def(
          "wait_for_frame_async",
          [](py::object self, uint64_t afterTick, double timeout) {
            return frameAsync(std::move(self), afterTick, timeout, false);
          },
          py::arg("after_tick") = 0, py::arg("timeout") = 5.0,
          "wait_for_frame() without blocking: an asyncio.Future of the first frame with a\n"
          "later tick, or of None after timeout seconds or once the subscription is closed.")
      .def("__aiter__", [](py::object self) { return self; })
      .def(
          "__anext__",
          [](py::object self) {
            const uint64_t after = self.cast<PySubscription&>().aiter.tick;
            return frameAsync(std::move(self), after, std::nullopt, true);
          },
          "`async for frame in sub`: each frame with a later tick than the one before (the\n"
          "first: the newest received, if any); ends when the subscription is closed.");
}

// ---------------------------------------------------------------------------------------------
// World as a context manager (docs/PYTHON.md "Worlds are durable"): the end of a `with` (or
// `async with`) block destroys a world that this World object created (create_world,
// create_world_async), so that a script leaves no world on the daemon, in memory or on its
// disk, unless it keeps one on purpose; a NotFound then (destroyed already, e.g. inside the
// block) is not an error. A World for an existing world (world(id), world_named()) is left as
// it is: the world may be another client's or shared, and destroying it cannot be undone.

/// An asyncio.Future of the running loop with this result already.
py::object resolvedFuture(py::object value) {
  py::object future = loopAndFuture().second;
  future.attr("set_result")(std::move(value));
  return future;
}

void defineWorldContext(py::module_& m) {
  auto world = py::reinterpret_borrow<py::class_<PyWorld>>(m.attr("World"));
  world
      .def_property_readonly(
          "created", &PyWorld::created,
          "Whether this World was made by create_world(): the end of a `with` block destroys\n"
          "it.")
      .def("__enter__", [](py::object self) { return self; })
      .def(
          "__exit__",
          [](PyWorld& w, const py::args&) {
            if (!w.created()) return;
            try {
              w.req(std::nullopt,
                    [](pc::WorldHandle h, pc::CallOptions o) { return h.destroy(o); });
            } catch (const pc::Error& e) {
              if (e.code() != pc::ErrorCode::NotFound) throw;
            }
          },
          "Destroys the world if this World created it (see created).")
      .def("__aenter__", [](py::object self) { return resolvedFuture(std::move(self)); })
      .def(
          "__aexit__",
          [](PyWorld& w, const py::args&) {
            if (!w.created()) return resolvedFuture(py::none());
            return worldAsync(
                w, std::nullopt, [](pc::WorldHandle h, pc::CallOptions o) { return h.destroy(o); },
                [](pc::Ack) { return py::object(py::none()); }, true);
          },
          "Destroys the world without blocking if this World created it (see created).");
}

/// The enums.
void defineEnums(py::module_& m) {
  py::enum_<pc::ErrorCode>(m, "ErrorCode", "The server's status codes (< 100) and the SDK's.")
      .value("Ok", pc::ErrorCode::Ok)
      .value("Malformed", pc::ErrorCode::Malformed)
      .value("InvalidArgument", pc::ErrorCode::InvalidArgument)
      .value("NotFound", pc::ErrorCode::NotFound)
      .value("IncorrectState", pc::ErrorCode::IncorrectState)
      .value("Unsupported", pc::ErrorCode::Unsupported)
      .value("ResourceExhausted", pc::ErrorCode::ResourceExhausted)
      .value("Internal", pc::ErrorCode::Internal)
      .value("PermissionDenied", pc::ErrorCode::PermissionDenied)
      .value("Moved", pc::ErrorCode::Moved)
      .value("Timeout", pc::ErrorCode::Timeout)
      .value("Disconnected", pc::ErrorCode::Disconnected)
      .value("Transport", pc::ErrorCode::Transport)
      .value("BadReply", pc::ErrorCode::BadReply);
  py::enum_<phys::BodyType>(m, "BodyType")
      .value("Static", phys::BodyType::Static)
      .value("Kinematic", phys::BodyType::Kinematic)
      .value("Dynamic", phys::BodyType::Dynamic);
  py::enum_<phys::ShapeType>(m, "ShapeType")
      .value("Sphere", phys::ShapeType::Sphere)
      .value("Box", phys::ShapeType::Box)
      .value("Capsule", phys::ShapeType::Capsule)
      .value("Plane", phys::ShapeType::Plane)
      .value("Hull", phys::ShapeType::Hull);
  py::enum_<phys::JointType>(m, "JointType")
      .value("Ball", phys::JointType::Ball)
      .value("Hinge", phys::JointType::Hinge)
      .value("Fixed", phys::JointType::Fixed)
      .value("Distance", phys::JointType::Distance)
      .value("Prismatic", phys::JointType::Prismatic);
  py::enum_<pc::PointFrame>(m, "PointFrame",
                            "Where the point of apply_force / apply_impulse is given.")
      .value("CenterOfMass", pc::PointFrame::CenterOfMass)
      .value("World", pc::PointFrame::World)
      .value("Local", pc::PointFrame::Local);
  py::enum_<pc::Event::Severity>(m, "Severity")
      .value("Info", pc::Event::Severity::Info)
      .value("Warning", pc::Event::Severity::Warning)
      .value("Error", pc::Event::Severity::Error);
}

/// physclient.Error and a subclass per ErrorCode.
void defineErrors(py::module_& m) {
  gError = PyErr_NewExceptionWithDoc(
      "physclient.Error",
      "A failed request: code (ErrorCode), message (the server's or the SDK's, without the "
      "code), from_server (whether the server answered with the code), retry_after_ms (a "
      "refusal of physd's rate or queue budgets: the same request may be sent again after so "
      "many ms; 0 for every other error).",
      PyExc_Exception, nullptr);
  if (!gError) throw py::error_already_set();
  m.attr("Error") = py::handle(gError);
  auto& classes = errorClasses();
  classes = {{pc::ErrorCode::Malformed, "Malformed", nullptr},
             {pc::ErrorCode::InvalidArgument, "InvalidArgument", nullptr},
             {pc::ErrorCode::NotFound, "NotFound", nullptr},
             {pc::ErrorCode::IncorrectState, "IncorrectState", nullptr},
             {pc::ErrorCode::Unsupported, "Unsupported", nullptr},
             {pc::ErrorCode::ResourceExhausted, "ResourceExhausted", nullptr},
             {pc::ErrorCode::Internal, "Internal", nullptr},
             {pc::ErrorCode::PermissionDenied, "PermissionDenied", nullptr},
             {pc::ErrorCode::Moved, "Moved", nullptr},
             {pc::ErrorCode::Timeout, "Timeout", PyExc_TimeoutError},
             {pc::ErrorCode::Disconnected, "Disconnected", PyExc_ConnectionError},
             {pc::ErrorCode::Transport, "Transport", nullptr},
             {pc::ErrorCode::BadReply, "BadReply", nullptr}};
  for (ErrorClass& c : classes) {
    const std::string qualified = std::string("physclient.") + c.name;
    py::tuple bases = c.extraBase ? py::make_tuple(py::handle(gError), py::handle(c.extraBase))
                                  : py::make_tuple(py::handle(gError));
    const std::string doc = std::string("physclient.Error with code ErrorCode.") + c.name + ".";
    c.cls = PyErr_NewExceptionWithDoc(qualified.c_str(), doc.c_str(), bases.ptr(), nullptr);
    if (!c.cls) throw py::error_already_set();
    m.attr(c.name) = py::handle(c.cls);
  }
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const pc::Error& e) {
      raiseError(e);
    }
  });
}

/// Material, ShapeGeom, ShapeDef, BodyDef, JointDef.
void defineDefinitions(py::module_& m) {
  py::class_<phys::Material>(m, "Material",
                             "Surface material: friction (>= 0), restitution (0..1), density "
                             "(kg/m^3, for masses computed from shapes).")
      .def(py::init([](py::kwargs kw) { return fromKwargs(phys::Material{}, kw, "Material"); }))
      .def_readwrite("friction", &phys::Material::friction)
      .def_readwrite("restitution", &phys::Material::restitution)
      .def_readwrite("density", &phys::Material::density)
      .def("__repr__", [](const phys::Material& mt) {
        return "Material(friction=" + std::to_string(mt.friction) +
               ", restitution=" + std::to_string(mt.restitution) +
               ", density=" + std::to_string(mt.density) + ")";
      });

  py::class_<phys::ShapeGeom>(m, "ShapeGeom",
                              "A shape's geometry in its local frame: make one with box(), "
                              "sphere(), capsule(), plane() or hull().")
      .def_static("box", &phys::ShapeGeom::box, py::arg("half_extents"),
                  "A box of these half extents (m).")
      .def_static("sphere", &phys::ShapeGeom::sphere, py::arg("radius"))
      .def_static("capsule", &phys::ShapeGeom::capsule, py::arg("radius"), py::arg("half_height"),
                  "A capsule along local z: radius and half the segment's length (m).")
      .def_static("plane", &phys::ShapeGeom::plane, py::arg("normal") = phys::Vec3{0, 0, 1},
                  py::arg("offset") = 0.0f,
                  "The plane dot(normal, x) = offset (static bodies only).")
      .def_static(
          "hull",
          [](std::vector<phys::Vec3> points) {
            // What needs no hull builder is checked here; whether the points span a volume,
            // the daemon that builds the hull says (the spawn fails with InvalidArgument).
            if (points.size() < 4)
              throw py::value_error("physclient: a convex hull needs at least 4 points, got " +
                                    std::to_string(points.size()));
            for (const phys::Vec3& p : points)
              if (!std::isfinite(p.x) || !std::isfinite(p.y) || !std::isfinite(p.z))
                throw py::value_error("physclient: a convex hull's points must be finite");
            return phys::ShapeGeom::hullOf(std::move(points));
          },
          py::arg("points"),
          "The convex hull of these points (m, local), at least 4, finite; the daemon builds it "
          "and refuses points that span no volume.")
      .def_readonly("type", &phys::ShapeGeom::type)
      .def_readwrite("radius", &phys::ShapeGeom::radius)
      .def_readwrite("half_extents", &phys::ShapeGeom::halfExtents)
      .def_readwrite("half_height", &phys::ShapeGeom::halfHeight)
      .def_readwrite("normal", &phys::ShapeGeom::normal)
      .def_readwrite("offset", &phys::ShapeGeom::offset)
      .def_property_readonly("hull_vertices",
                             [](const phys::ShapeGeom& g) {
                               return g.hull ? g.hull->vertices : std::vector<phys::Vec3>{};
                             })
      .def("__repr__", [](const phys::ShapeGeom& g) {
        return std::string("ShapeGeom(") + phys::toString(g.type) + ")";
      });

  py::class_<phys::ShapeDef>(m, "ShapeDef",
                             "One shape of a body: geom, local_position and local_rotation "
                             "(its frame in the body's), material.")
      .def(py::init([](const phys::ShapeGeom& geom, py::kwargs kw) {
             phys::ShapeDef s;
             s.geom = geom;
             return fromKwargs(std::move(s), kw, "ShapeDef");
           }),
           py::arg("geom"))
      .def_readwrite("geom", &phys::ShapeDef::geom)
      .def_property(
          "local_position", [](const phys::ShapeDef& s) { return s.local.p; },
          [](phys::ShapeDef& s, phys::Vec3 p) { s.local.p = p; })
      .def_property(
          "local_rotation", [](const phys::ShapeDef& s) { return s.local.q; },
          [](phys::ShapeDef& s, phys::Quat q) { s.local.q = q; })
      .def_readwrite("material", &phys::ShapeDef::material)
      .def("__repr__", [](const phys::ShapeDef& s) {
        return std::string("ShapeDef(") + phys::toString(s.geom.type) + ")";
      });

  py::class_<phys::BodyDef>(
      m, "BodyDef",
      "A body to spawn; keyword arguments set its fields: type (BodyType), position, rotation\n"
      "(x, y, z, w), linear_velocity, angular_velocity, linear_damping, angular_damping,\n"
      "gravity_scale, mass (0: from the shapes' densities), inertia, gyroscopic, allow_sleep,\n"
      "name, shapes (a list of ShapeDef; assign a new list to change it).")
      .def(py::init([](py::kwargs kw) { return fromKwargs(phys::BodyDef{}, kw, "BodyDef"); }))
      .def_readwrite("type", &phys::BodyDef::type)
      .def_readwrite("position", &phys::BodyDef::position)
      .def_readwrite("rotation", &phys::BodyDef::rotation)
      .def_readwrite("linear_velocity", &phys::BodyDef::linearVelocity)
      .def_readwrite("angular_velocity", &phys::BodyDef::angularVelocity)
      .def_readwrite("linear_damping", &phys::BodyDef::linearDamping)
      .def_readwrite("angular_damping", &phys::BodyDef::angularDamping)
      .def_readwrite("gravity_scale", &phys::BodyDef::gravityScale)
      .def_readwrite("mass", &phys::BodyDef::mass)
      .def_readwrite("inertia", &phys::BodyDef::inertia)
      .def_readwrite("gyroscopic", &phys::BodyDef::gyroscopic)
      .def_readwrite("allow_sleep", &phys::BodyDef::allowSleep)
      .def_readwrite("name", &phys::BodyDef::name)
      .def_readwrite("shapes", &phys::BodyDef::shapes)
      .def("__repr__", [](const phys::BodyDef& b) {
        return std::string("BodyDef(") + phys::toString(b.type) + ", position=" +
               reprOf(b.position) + ", shapes=" + std::to_string(b.shapes.size()) + ")";
      });

  py::class_<phys::JointDef>(
      m, "JointDef",
      "A joint to add; keyword arguments set its fields: type (JointType), body_a, body_b\n"
      "(body ids; body_a 0: anchored to the world), anchor_a, anchor_b (local to each body),\n"
      "axis_a, axis_b, enable_limit, lower, upper, enable_motor, motor_speed,\n"
      "max_motor_force, length (< 0: the initial distance), spring_hertz,\n"
      "spring_damping_ratio, collide_connected, name.")
      .def(py::init([](py::kwargs kw) { return fromKwargs(phys::JointDef{}, kw, "JointDef"); }))
      .def_readwrite("type", &phys::JointDef::type)
      .def_property(
          "body_a", [](const phys::JointDef& j) { return j.bodyA.packed(); },
          [](phys::JointDef& j, uint64_t id) { j.bodyA = phys::BodyId::fromPacked(id); })
      .def_property(
          "body_b", [](const phys::JointDef& j) { return j.bodyB.packed(); },
          [](phys::JointDef& j, uint64_t id) { j.bodyB = phys::BodyId::fromPacked(id); })
      .def_readwrite("anchor_a", &phys::JointDef::anchorA)
      .def_readwrite("anchor_b", &phys::JointDef::anchorB)
      .def_readwrite("axis_a", &phys::JointDef::axisA)
      .def_readwrite("axis_b", &phys::JointDef::axisB)
      .def_readwrite("enable_limit", &phys::JointDef::enableLimit)
      .def_readwrite("lower", &phys::JointDef::lower)
      .def_readwrite("upper", &phys::JointDef::upper)
      .def_readwrite("enable_motor", &phys::JointDef::enableMotor)
      .def_readwrite("motor_speed", &phys::JointDef::motorSpeed)
      .def_readwrite("max_motor_force", &phys::JointDef::maxMotorForce)
      .def_readwrite("length", &phys::JointDef::length)
      .def_readwrite("spring_hertz", &phys::JointDef::springHertz)
      .def_readwrite("spring_damping_ratio", &phys::JointDef::springDampingRatio)
      .def_readwrite("collide_connected", &phys::JointDef::collideConnected)
      .def_readwrite("name", &phys::JointDef::name)
      .def("__repr__", [](const phys::JointDef& j) {
        return std::string("JointDef(") + phys::toString(j.type) + ", body_a=" +
               std::to_string(j.bodyA.packed()) + ", body_b=" + std::to_string(j.bodyB.packed()) +
               ")";
      });
}

/// What requests return: ServerInfo, Ack, Ids, BodyState, BodyArray, StateFrame.
void defineResults(py::module_& m) {
  py::class_<pc::ServerInfo>(m, "ServerInfo", "What the server said in HelloResult.")
      .def_readonly("protocol_version", &pc::ServerInfo::protocolVersion)
      .def_readonly("name", &pc::ServerInfo::name)
      .def_readonly("version", &pc::ServerInfo::version)
      .def_readonly("features", &pc::ServerInfo::features)
      .def_readonly("client_proven", &pc::ServerInfo::clientProven)
      .def("__repr__", [](const pc::ServerInfo& s) {
        return "ServerInfo(name='" + s.name + "', version='" + s.version +
               "', protocol_version=" + std::to_string(s.protocolVersion) + ")";
      });

  py::class_<pc::Ack>(m, "Ack", "A request's effect: the world and the tick (step: after it).")
      .def_readonly("world", &pc::Ack::world)
      .def_readonly("tick", &pc::Ack::tick)
      .def("__repr__", [](const pc::Ack& a) {
        return "Ack(world=" + std::to_string(a.world) + ", tick=" + std::to_string(a.tick) + ")";
      });

  py::class_<pc::Ids>(m, "Ids", "Bodies and joints a scene made.")
      .def_readonly("bodies", &pc::Ids::bodies)
      .def_readonly("joints", &pc::Ids::joints)
      .def("__repr__", [](const pc::Ids& i) {
        return "Ids(bodies=" + std::to_string(i.bodies.size()) +
               ", joints=" + std::to_string(i.joints.size()) + ")";
      });

  py::class_<pc::BodyState>(m, "BodyState", "One body at one tick.")
      .def_readonly("id", &pc::BodyState::id)
      .def_readonly("position", &pc::BodyState::position)
      .def_readonly("rotation", &pc::BodyState::rotation)
      .def_readonly("linear_velocity", &pc::BodyState::linearVelocity)
      .def_readonly("angular_velocity", &pc::BodyState::angularVelocity)
      .def_readonly("changed", &pc::BodyState::changed)
      .def("__repr__", [](const pc::BodyState& b) {
        return "BodyState(id=" + std::to_string(b.id) + ", position=" + reprOf(b.position) + ")";
      });

  py::class_<BodyArray>(m, "BodyArray", py::buffer_protocol(),
                        "A frame's bodies as a (n, 13) float32 buffer (memoryview, "
                        "numpy.asarray): position xyz, rotation xyzw, linear velocity xyz, "
                        "angular velocity xyz.")
      .def_buffer([](BodyArray& a) {
        return py::buffer_info(a.data.data(), sizeof(float), py::format_descriptor<float>::format(),
                               2, {a.rows, BodyArray::kColumns},
                               {sizeof(float) * BodyArray::kColumns, sizeof(float)});
      })
      .def("__len__", [](const BodyArray& a) { return a.rows; })
      .def_property_readonly_static("COLUMNS", [](py::object) {
        return py::make_tuple("px", "py", "pz", "qx", "qy", "qz", "qw", "vx", "vy", "vz", "wx",
                              "wy", "wz");
      });

  py::class_<pc::StateFrame>(m, "StateFrame",
                             "A world's bodies at one tick (a subscription's frame or a "
                             "query_state answer). bodies is a new list at each access.")
      .def_readonly("world", &pc::StateFrame::world)
      .def_readonly("tick", &pc::StateFrame::tick)
      .def_readonly("time", &pc::StateFrame::time)
      .def_readonly("total", &pc::StateFrame::total)
      .def_readonly("bodies", &pc::StateFrame::bodies)
      .def_readonly("keyframe", &pc::StateFrame::keyframe)
      .def_readonly("changed", &pc::StateFrame::changed)
      .def_readonly("bytes", &pc::StateFrame::bytes)
      .def_readonly("stamp_ns", &pc::StateFrame::stampNs)
      .def_readonly("epoch", &pc::StateFrame::epoch,
                    "Higher after the world was reset, restored or loaded (its ticks start "
                    "again there).")
      .def_readonly("edit", &pc::StateFrame::edit,
                    "1, 2, ... for frames of edits to a paused world at this tick; else 0.")
      .def_property_readonly("ids",
                             [](const pc::StateFrame& f) {
                               std::vector<uint64_t> ids;
                               ids.reserve(f.bodies.size());
                               for (const auto& b : f.bodies) ids.push_back(b.id);
                               return ids;
                             })
      .def(
          "find",
          [](const pc::StateFrame& f, uint64_t id) -> std::optional<pc::BodyState> {
            for (const auto& b : f.bodies)
              if (b.id == id) return b;
            return std::nullopt;
          },
          py::arg("id"), "The state of body id, or None.")
      .def(
          "array", [](const pc::StateFrame& f) { return BodyArray(f.bodies); },
          "The bodies as a BodyArray (a buffer of (n, 13) float32), in the order of bodies.")
      .def("__len__", [](const pc::StateFrame& f) { return f.bodies.size(); })
      .def("__repr__", [](const pc::StateFrame& f) {
        return "StateFrame(world=" + std::to_string(f.world) + ", tick=" + std::to_string(f.tick) +
               ", bodies=" + std::to_string(f.bodies.size()) + ")";
      });
}

/// What a world reports: WorldSummary, WorldSettings, BodyInfo, JointInfo, their pages, ServerStatus, Event.
void defineWorldResults(py::module_& m) {
  py::class_<pc::WorldSummary>(m, "WorldSummary", "A world as list_worlds() reports it.")
      .def_readonly("world", &pc::WorldSummary::world)
      .def_readonly("daemon", &pc::WorldSummary::daemon)
      .def_readonly("moving_to", &pc::WorldSummary::movingTo)
      .def_readonly("name", &pc::WorldSummary::name)
      .def_readonly("preset", &pc::WorldSummary::preset)
      .def_readonly("bodies", &pc::WorldSummary::bodies)
      .def_readonly("joints", &pc::WorldSummary::joints)
      .def_readonly("tick", &pc::WorldSummary::tick)
      .def_readonly("time", &pc::WorldSummary::time)
      .def_readonly("running", &pc::WorldSummary::running)
      .def_readonly("rate_hz", &pc::WorldSummary::rateHz)
      .def_readonly("tick_ms", &pc::WorldSummary::tickMs)
      .def_readonly("tick_ms_max", &pc::WorldSummary::tickMsMax)
      .def_readonly("overruns", &pc::WorldSummary::overruns)
      .def_readonly("subscribers", &pc::WorldSummary::subscribers)
      .def_readonly("frames", &pc::WorldSummary::frames)
      .def_readonly("backend", &pc::WorldSummary::backend)
      .def_readonly("device", &pc::WorldSummary::device)
      .def_readonly("backend_note", &pc::WorldSummary::backendNote)
      .def_readonly("gpu_steps", &pc::WorldSummary::gpuSteps)
      .def_readonly("cpu_steps", &pc::WorldSummary::cpuSteps)
      .def_readonly("awake_bodies", &pc::WorldSummary::awakeBodies)
      .def_readonly("sleeping_bodies", &pc::WorldSummary::sleepingBodies)
      .def_readonly("frame_bytes", &pc::WorldSummary::frameBytes)
      .def_readonly("contacts", &pc::WorldSummary::contacts)
      .def_readonly("step_buffer_bytes", &pc::WorldSummary::stepBufferBytes)
      .def_readonly("damage", &pc::WorldSummary::damage)
      .def("__repr__", [](const pc::WorldSummary& w) {
        return "WorldSummary(world=" + std::to_string(w.world) + ", name='" + w.name +
               "', bodies=" + std::to_string(w.bodies) + ", tick=" + std::to_string(w.tick) +
               ", running=" + (w.running ? "True" : "False") + ")";
      });

  py::class_<pc::WorldSettings>(
      m, "WorldSettings",
      "A world's settings (World.settings()): every keyword set_world takes, the solver's\n"
      "settings as set_solver's keywords (a dict), the preset last applied, and the tick.")
      // One property per world setting (PHYS_WORLD_FIELDS), named as set_world's keyword.
#define PHYS_WORLD_PROPERTY(type, member, path, name) \
  .def_property_readonly(#name, [](const pc::WorldSettings& s) { return s.def.path; })
      PHYS_WORLD_FIELDS(PHYS_WORLD_PROPERTY)
#undef PHYS_WORLD_PROPERTY
      .def_property_readonly("solver",
                             [](const pc::WorldSettings& s) { return solverDict(s.def.solver); })
      .def_readonly("preset", &pc::WorldSettings::preset)
      .def_readonly("tick", &pc::WorldSettings::tick)
      .def("__repr__", [](const pc::WorldSettings& s) {
        return "WorldSettings(gravity=" + reprOf(s.def.gravity) +
               ", time_step=" + std::to_string(s.def.timeStep) +
               ", sleep=" + (s.def.sleep.enabled ? "True" : "False") + ", preset='" + s.preset +
               "')";
      });

  py::class_<pc::BodyInfo>(
      m, "BodyInfo",
      "A body as its world simulates it (World.get_bodies): id, definition (a BodyDef: pose\n"
      "and velocities as of the reply's tick; mass and inertia as given, 0: from the shapes),\n"
      "and the mass properties the world derived: mass (kg), center_of_mass (body frame),\n"
      "inertia (principal moments), inertia_axes (their frame in the body's, x, y, z, w).")
      .def_readonly("id", &pc::BodyInfo::id)
      .def_readonly("definition", &pc::BodyInfo::def)
      .def_property_readonly("mass", [](const pc::BodyInfo& b) { return b.mass.mass; })
      .def_property_readonly("center_of_mass",
                             [](const pc::BodyInfo& b) { return b.mass.localCenter; })
      .def_property_readonly("inertia", [](const pc::BodyInfo& b) { return b.mass.inertia; })
      .def_property_readonly("inertia_axes",
                             [](const pc::BodyInfo& b) { return b.mass.inertiaRotation; })
      .def("__repr__", [](const pc::BodyInfo& b) {
        return "BodyInfo(id=" + std::to_string(b.id) + ", name='" + b.def.name +
               "', mass=" + std::to_string(b.mass.mass) + ")";
      });

  py::class_<pc::JointInfo>(m, "JointInfo",
                            "A joint's definition (World.get_joints): id, definition (a "
                            "JointDef; body_a 0: the world).")
      .def_readonly("id", &pc::JointInfo::id)
      .def_readonly("definition", &pc::JointInfo::def)
      .def("__repr__", [](const pc::JointInfo& j) {
        return "JointInfo(id=" + std::to_string(j.id) + ", name='" + j.def.name + "')";
      });

  py::class_<pc::BodiesPage>(m, "BodiesPage",
                             "One reply of get_bodies: tick, total (what matched before "
                             "paging), bodies (a list of BodyInfo).")
      .def_readonly("tick", &pc::BodiesPage::tick)
      .def_readonly("total", &pc::BodiesPage::total)
      .def_readonly("bodies", &pc::BodiesPage::bodies)
      .def("__len__", [](const pc::BodiesPage& p) { return p.bodies.size(); });

  py::class_<pc::JointsPage>(m, "JointsPage",
                             "One reply of get_joints: tick, total, joints (JointInfo).")
      .def_readonly("tick", &pc::JointsPage::tick)
      .def_readonly("total", &pc::JointsPage::total)
      .def_readonly("joints", &pc::JointsPage::joints)
      .def("__len__", [](const pc::JointsPage& p) { return p.joints.size(); });

  py::class_<pc::ServerStatus>(m, "ServerStatus", "The latest phys/status sample.")
      .def_readonly("server_name", &pc::ServerStatus::serverName)
      .def_readonly("server_version", &pc::ServerStatus::serverVersion)
      .def_readonly("uptime_s", &pc::ServerStatus::uptimeS)
      .def_readonly("commands", &pc::ServerStatus::commands)
      .def_readonly("errors", &pc::ServerStatus::errors)
      .def_readonly("worlds", &pc::ServerStatus::worlds)
      .def_readonly("frames_dropped", &pc::ServerStatus::framesDropped)
      .def_readonly("heap_bytes", &pc::ServerStatus::heapBytes)
      .def_readonly("read_only", &pc::ServerStatus::readOnly)
      .def_readonly("daemon", &pc::ServerStatus::daemon)
      .def_readonly("cluster", &pc::ServerStatus::cluster)
      .def_readonly("status_period_s", &pc::ServerStatus::statusPeriodS)
      .def_readonly("peers", &pc::ServerStatus::peers);

  py::class_<pc::DaemonInfo>(m, "DaemonInfo", "A daemon of the domain (Client.daemons()).")
      .def_readonly("id", &pc::DaemonInfo::id)
      .def_readonly("name", &pc::DaemonInfo::name)
      .def_readonly("cluster", &pc::DaemonInfo::cluster)
      .def_readonly("worlds", &pc::DaemonInfo::worlds)
      .def_readonly("awake_bodies", &pc::DaemonInfo::awakeBodies)
      .def_readonly("since_sample_s", &pc::DaemonInfo::sinceSampleS)
      .def_readonly("peers", &pc::DaemonInfo::peers)
      .def("__repr__", [](const pc::DaemonInfo& d) {
        return "DaemonInfo(id=" + std::to_string(d.id) + ", name='" + d.name +
               "', worlds=" + std::to_string(d.worlds) + ")";
      });

  py::class_<pc::Event>(m, "Event", "A notice from the daemon (phys/events).")
      .def_readonly("world", &pc::Event::world)
      .def_readonly("tick", &pc::Event::tick)
      .def_readonly("severity", &pc::Event::severity)
      .def_readonly("code", &pc::Event::code)
      .def_readonly("message", &pc::Event::message)
      .def("__repr__", [](const pc::Event& e) {
        return "Event(world=" + std::to_string(e.world) + ", tick=" + std::to_string(e.tick) +
               ", code='" + e.code + "')";
      });
}

/// Subscription.
void defineSubscription(py::module_& m) {
  py::class_<PySubscription>(
      m, "Subscription",
      "A live subscription to a world's state frames; close() (or the end of a with block, or\n"
      "the object's collection) unsubscribes. A callback, if given, runs on the SDK's thread\n"
      "for every complete tick with a StateFrame of its own.")
      .def("latest", &PySubscription::latest, "The newest complete frame, or None.")
      .def("wait_for_frame", &PySubscription::waitForFrame, py::arg("after_tick") = 0,
           py::arg("timeout") = 5.0,
           "Waits up to timeout seconds for a frame with tick > after_tick, or of a newer\n"
           "epoch than the last frame latest() or wait_for_frame() returned (the world was\n"
           "reset or restored: its ticks started again); None if none came. Before they\n"
           "returned any, after_tick 0 takes the first frame, whatever its tick.")
      .def_property_readonly("frames_received", &PySubscription::framesReceived)
      .def_property_readonly("frames_skipped", &PySubscription::framesSkipped)
      .def_property_readonly("stale_chunks", &PySubscription::staleChunks,
                             "Frame chunks dropped because their epoch was below the stream's\n"
                             "(late frames of a reset world, or a deposed owner's).")
      .def_property_readonly("world", &PySubscription::world)
      .def_property_readonly("active", &PySubscription::active, "False once closed.")
      .def("close", &PySubscription::close)
      .def("__enter__", [](py::object self) { return self; })
      .def("__exit__", [](PySubscription& s, py::args) { s.close(); });
}

/// World: its blocking requests (defineWorldMore has the rest).
void defineWorld(py::module_& m) {
  using OptS = std::optional<double>;
  const auto T = py::arg("timeout") = py::none();
  py::class_<PyWorld>(m, "World",
                      "A world of the server. Every request blocks until physd answers (or "
                      "timeout seconds: None for the client's request_timeout) and raises "
                      "physclient.Error when it fails.")
      .def_property_readonly("id", &PyWorld::id)
      .def("info", &PyWorld::info, py::kw_only(), T,
           "This world's WorldSummary (from list_worlds).")
      .def(
          "destroy",
          [](PyWorld& w, OptS t) {
            return w.req(t, [](pc::WorldHandle h, pc::CallOptions o) { return h.destroy(o); });
          },
          py::kw_only(), T)
      .def(
          "reset",
          [](PyWorld& w, OptS t) {
            return w.req(t, [](pc::WorldHandle h, pc::CallOptions o) { return h.reset(o); });
          },
          py::kw_only(), T)
      .def(
          "load_scene",
          [](PyWorld& w, const std::string& name, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.loadScene(name, o);
            });
          },
          py::arg("name"), py::kw_only(), T,
          "A scene of the server's scene folder by name (configs/scenes/<name>.json) -> Ids.")
      .def(
          "load_scene_json",
          [](PyWorld& w, const std::string& json, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.loadSceneJson(json, o);
            });
          },
          py::arg("json"), py::kw_only(), T, "A scene given as JSON text -> Ids.")
      .def(
          "spawn",
          [](PyWorld& w, const py::object& bodies, OptS t) {
            auto defs = oneOrMany<phys::BodyDef>(bodies, "BodyDef");
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.spawn(std::span<const phys::BodyDef>(defs), o);
            });
          },
          py::arg("bodies"), py::kw_only(), T,
          "Spawns a BodyDef or a list of them -> their ids, in order.")
      .def(
          "remove_bodies",
          [](PyWorld& w, const py::object& ids, OptS t) {
            auto v = idList(ids);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.removeBodies(std::span<const uint64_t>(v), o);
            });
          },
          py::arg("ids"), py::kw_only(), T)
      .def(
          "add_joints",
          [](PyWorld& w, const py::object& joints, OptS t) {
            auto defs = oneOrMany<phys::JointDef>(joints, "JointDef");
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.addJoints(std::span<const phys::JointDef>(defs), o);
            });
          },
          py::arg("joints"), py::kw_only(), T, "Adds a JointDef or a list of them -> joint ids.")
      .def(
          "remove_joints",
          [](PyWorld& w, const py::object& ids, OptS t) {
            auto v = idList(ids);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.removeJoints(std::span<const uint64_t>(v), o);
            });
          },
          py::arg("ids"), py::kw_only(), T)
      .def(
          "set_pose",
          [](PyWorld& w, uint64_t body, phys::Vec3 p, phys::Quat q, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.setPose(body, p, q, o);
            });
          },
          py::arg("body"), py::arg("position"), py::arg("rotation") = phys::Quat{}, py::kw_only(),
          T)
      .def(
          "set_velocity",
          [](PyWorld& w, uint64_t body, phys::Vec3 lin, phys::Vec3 ang, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.setVelocity(body, lin, ang, o);
            });
          },
          py::arg("body"), py::arg("linear"), py::arg("angular") = phys::Vec3{}, py::kw_only(), T)
      .def(
          "apply_force",
          [](PyWorld& w, uint64_t body, phys::Vec3 f, phys::Vec3 point, pc::PointFrame frame,
             OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.applyForce(body, f, point, frame, o);
            });
          },
          py::arg("body"), py::arg("force"), py::arg("point") = phys::Vec3{},
          py::arg("frame") = pc::PointFrame::CenterOfMass, py::kw_only(), T,
          "A force (N) acting during the next step only.")
      .def(
          "apply_impulse",
          [](PyWorld& w, uint64_t body, phys::Vec3 j, phys::Vec3 point, pc::PointFrame frame,
             OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.applyImpulse(body, j, point, frame, o);
            });
          },
          py::arg("body"), py::arg("impulse"), py::arg("point") = phys::Vec3{},
          py::arg("frame") = pc::PointFrame::CenterOfMass, py::kw_only(), T,
          "An impulse (N s), applied now.")
      .def(
          "apply_torque",
          [](PyWorld& w, uint64_t body, phys::Vec3 torque, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.applyTorque(body, torque, o);
            });
          },
          py::arg("body"), py::arg("torque"), py::kw_only(), T,
          "A torque (N m) acting during the next step only.")
      .def(
          "set_material",
          [](PyWorld& w, const py::object& bodies, const phys::Material& mt, OptS t) {
            auto v = idList(bodies);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.setMaterial(std::span<const uint64_t>(v), mt, o);
            });
          },
          py::arg("bodies"), py::arg("material"), py::kw_only(), T,
          "Every shape of each body gets this material.")
      .def(
          "set_solver",
          [](PyWorld& w, const std::string& preset, OptS t, const py::kwargs& kw) {
            const pc::SolverOverrides ov = solverOverrides(kw);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.setSolver(preset, ov, o);
            });
          },
          py::arg("preset") = "", py::kw_only(), T,
          "A solver preset (\"\": keep the world's) and overrides as keywords: iterations=,\n"
          "substeps=, scheme='GaussSeidel'|'Jacobi'|'ColoredGaussSeidel', warm_start=, ...");
}

/// World's blocking requests after set_solver, and its comparisons.
void defineWorldMore(py::module_& m) {
  using OptS = std::optional<double>;
  const auto T = py::arg("timeout") = py::none();
  auto world = py::reinterpret_borrow<py::class_<PyWorld>>(m.attr("World"));
  world
      .def(
          "set_world",
          [](PyWorld& w, OptS t, const py::kwargs& kw) {
            const pc::WorldOverrides ov = worldOverrides(kw);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.setWorld(ov, o);
            });
          },
          py::kw_only(), T,
          "Changes the world's settings given as keywords, all or nothing (docs/PYTHON.md):\n"
          "gravity=(x, y, z), time_step=, sleep=True|False, sleep_time=,\n"
          "sleep_linear_speed=, sleep_angular_speed=, max_linear_speed=, max_angular_speed=,\n"
          "speculative_distance=, aabb_margin=, guard=, guard_energy_jump=, guard_retries=.\n"
          "A gravity change wakes every body. -> Ack")
      .def(
          "set_gravity",
          [](PyWorld& w, phys::Vec3 g, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.setGravity(g, o);
            });
          },
          py::arg("gravity"), py::kw_only(), T, "set_world(gravity=...): wakes every body.")
      .def(
          "settings",
          [](PyWorld& w, OptS t) {
            return w.req(t, [](pc::WorldHandle h, pc::CallOptions o) { return h.settings(o); });
          },
          py::kw_only(), T, "The world's settings -> WorldSettings.")
      .def(
          "get_bodies",
          [](PyWorld& w, const py::object& ids, uint32_t first, uint32_t maxCount, OptS t) {
            auto v = idList(ids);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.getBodies(std::span<const uint64_t>(v), first, maxCount, o);
            });
          },
          py::arg("ids") = py::none(), py::arg("first") = 0, py::arg("max_count") = 0,
          py::kw_only(), T,
          "Definitions as the world simulates them, of these ids (None: every body, paged by\n"
          "first / max_count) -> BodiesPage, which may hold fewer than asked: ask again from\n"
          "where it ended, or use all_bodies().")
      .def(
          "get_joints",
          [](PyWorld& w, const py::object& ids, uint32_t first, uint32_t maxCount, OptS t) {
            auto v = idList(ids);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.getJoints(std::span<const uint64_t>(v), first, maxCount, o);
            });
          },
          py::arg("ids") = py::none(), py::arg("first") = 0, py::arg("max_count") = 0,
          py::kw_only(), T, "Joint definitions, as get_bodies -> JointsPage.")
      .def(
          "all_bodies",
          [](PyWorld& w, OptS t) {
            return w.req(t, [](pc::WorldHandle h, pc::CallOptions o) { return h.allBodies(o); });
          },
          py::kw_only(), T, "Every body's definition, page after page -> a list of BodyInfo.")
      .def(
          "all_joints",
          [](PyWorld& w, OptS t) {
            return w.req(t, [](pc::WorldHandle h, pc::CallOptions o) { return h.allJoints(o); });
          },
          py::kw_only(), T, "Every joint's definition -> a list of JointInfo.")
      .def(
          "step",
          [](PyWorld& w, uint32_t n, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) { return h.step(n, o); });
          },
          py::arg("n") = 1, py::kw_only(), T,
          "Takes n steps now -> Ack whose tick is the tick after them.")
      .def(
          "run",
          [](PyWorld& w, float rate, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) { return h.run(rate, o); });
          },
          py::arg("rate_hz") = 60.0f, py::kw_only(), T,
          "Runs in real time at rate_hz (0: as fast as possible).")
      .def(
          "pause",
          [](PyWorld& w, OptS t) {
            return w.req(t, [](pc::WorldHandle h, pc::CallOptions o) { return h.pause(o); });
          },
          py::kw_only(), T)
      .def(
          "move",
          [](PyWorld& w, uint64_t daemon, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) { return h.move(daemon, o); });
          },
          py::arg("daemon"), py::kw_only(), T,
          "To that daemon (server.id) of the domain, at a tick boundary -> Ack (the last tick\n"
          "taken where it was); the World goes on working (docs/CLIENT.md \"Several daemons\").")
      .def(
          "set_access",
          [](PyWorld& w, const py::object& editors, bool shared, OptS t) {
            auto v = idList(editors);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.setAccess(std::span<const uint64_t>(v), shared, o);
            });
          },
          py::arg("editors") = py::list(), py::arg("shared") = false, py::kw_only(), T,
          "The owner only: client ids that may change the world too, or shared: every client.")
      .def(
          "query_state",
          [](PyWorld& w, const py::object& ids, uint32_t first, uint32_t maxCount, OptS t) {
            auto v = idList(ids);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.queryState(std::span<const uint64_t>(v), first, maxCount, o);
            });
          },
          py::arg("ids") = py::none(), py::arg("first") = 0, py::arg("max_count") = 0,
          py::kw_only(), T,
          "These bodies' states (None: every body, paged by first / max_count) -> StateFrame.")
      .def(
          "save_snapshot",
          [](PyWorld& w, OptS t) {
            pc::Bytes b = w.req(
                t, [](pc::WorldHandle h, pc::CallOptions o) { return h.saveSnapshot(o); });
            return py::bytes(reinterpret_cast<const char*>(b.data()), b.size());
          },
          py::kw_only(), T, "The engine's exact snapshot of the world -> bytes.")
      .def(
          "save_snapshot_file",
          [](PyWorld& w, const std::string& file, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.saveSnapshotFile(file, o);
            });
          },
          py::arg("file"), py::kw_only(), T, "Saved on the server, in its snapshot folder.")
      .def(
          "restore_snapshot",
          [](PyWorld& w, const py::buffer& data, OptS t) {
            const std::vector<uint8_t> bytes = bytesOf(data);
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.restoreSnapshot(std::span<const uint8_t>(bytes), o);
            });
          },
          py::arg("snapshot"), py::kw_only(), T,
          "Puts the world back as save_snapshot() saw it (bytes or any buffer).")
      .def(
          "restore_snapshot_file",
          [](PyWorld& w, const std::string& file, OptS t) {
            return w.req(t, [&](pc::WorldHandle h, pc::CallOptions o) {
              return h.restoreSnapshotFile(file, o);
            });
          },
          py::arg("file"), py::kw_only(), T)
      .def("subscribe", &PyWorld::subscribe, py::arg("callback") = py::none(), py::kw_only(),
           py::arg("bodies") = py::none(), py::arg("region") = py::none(), T,
           "State frames of this world -> Subscription. callback(frame), if given, runs on the\n"
           "SDK's thread for every complete tick. bodies (ids) or region ((min corner, max\n"
           "corner)): only those bodies (an interest of physd's, asked for as a request).",
           py::return_value_policy::take_ownership)
      .def("__eq__",
           [](const PyWorld& a, const PyWorld& b) { return a.box() == b.box() && a.id() == b.id(); })
      .def("__hash__", [](const PyWorld& w) { return py::hash(py::int_(w.id())); })
      .def("__repr__", [](const PyWorld& w) { return "World(" + std::to_string(w.id()) + ")"; });
}

/// Client.
void defineClient(py::module_& m) {
  using OptS = std::optional<double>;
  const auto T = py::arg("timeout") = py::none();
  py::class_<PyClient>(
      m, "Client",
      "A connection to physd: DDS entities and the SDK's thread, made at once; connect()\n"
      "waits for a daemon. cyclone_xml is the Cyclone DDS XML text (None: CYCLONEDDS_URI or\n"
      "Cyclone's defaults). Timeouts are in seconds. security_dir and identity: DDS Security\n"
      "files as tools/make_security.sh writes them (docs/SECURITY.md). key_file: the client's\n"
      "key (made when missing): the same proven client id at every run, so the worlds it\n"
      "creates stay its own (docs/SERVER.md \"Access\"). retry_busy: a request physd refuses\n"
      "at the door (ResourceExhausted \"slow down\" / \"wait for replies\" from its rate and\n"
      "queue budgets; nothing done) is sent again after a backoff until its timeout (False:\n"
      "the refusal raises at once; docs/PYTHON.md \"Rate limits\"). The connection lasts\n"
      "while the Client or one of its World or Subscription objects does, or until close()\n"
      "(or the end of a with block).")
      .def(py::init<uint32_t, std::string, std::optional<std::string>, uint64_t, double, double,
                    bool, std::optional<std::string>, std::optional<std::string>,
                    std::optional<std::string>, bool>(),
           py::kw_only(), py::arg("domain") = 0, py::arg("name") = "physclient-python",
           py::arg("cyclone_xml") = py::none(), py::arg("client_id") = 0,
           py::arg("connect_timeout") = 10.0, py::arg("request_timeout") = 10.0,
           py::arg("auto_reconnect") = true, py::arg("security_dir") = py::none(),
           py::arg("identity") = py::none(), py::arg("key_file") = py::none(),
           py::arg("retry_busy") = true)
      .def(
          "connect",
          [](PyClient& c) {
            return blocking(c.box(), [](pc::Client& cl) { return cl.connect(); });
          },
          "Waits for physd on the domain and says Hello -> ServerInfo (Timeout if none "
          "answers within connect_timeout).")
      .def("close", &PyClient::close, "Ends the connection (pending requests fail).")
      .def_property_readonly("closed", &PyClient::closed)
      .def_property_readonly(
          "connected",
          [](PyClient& c) { return quick(c.box(), [](pc::Client& cl) { return cl.connected(); }); })
      .def_property_readonly(
          "reconnects",
          [](PyClient& c) { return quick(c.box(), [](pc::Client& cl) { return cl.reconnects(); }); })
      .def_property_readonly(
          "client_id",
          [](PyClient& c) { return quick(c.box(), [](pc::Client& cl) { return cl.clientId(); }); })
      .def_property_readonly(
          "domain",
          [](PyClient& c) {
            return quick(c.box(), [](pc::Client& cl) { return cl.options().domain; });
          })
      .def_property_readonly(
          "server",
          [](PyClient& c) { return quick(c.box(), [](pc::Client& cl) { return cl.server(); }); },
          "What the last Hello answered (ServerInfo).")
      .def(
          "hello",
          [](PyClient& c, OptS t) {
            return request(c.box(), [&](pc::Client& cl) { return cl.hello(callOptions(t)); });
          },
          py::kw_only(), T)
      .def(
          "create_world",
          [](PyClient& c, const std::string& name, const std::string& preset,
             std::optional<phys::Vec3> gravity, float timeStep, const std::string& backend,
             bool sleep, bool ephemeral, const py::object& editors, bool shared, uint64_t daemon,
             OptS t) {
            pc::CreateWorldArgs a;
            a.name = name;
            a.preset = preset;
            a.gravity = gravity;
            a.timeStep = timeStep;
            a.backend = backend;
            a.sleep = sleep;
            a.ephemeral = ephemeral;
            a.editors = idList(editors);
            a.shared = shared;
            pc::CallOptions o = callOptions(t);
            o.daemon = daemon;
            pc::WorldHandle h =
                request(c.box(), [&](pc::Client& cl) { return cl.createWorld(a, o); });
            return PyWorld(c.box(), h.id()).markCreated();
          },
          py::arg("name"), py::arg("preset") = "", py::kw_only(), py::arg("gravity") = py::none(),
          py::arg("time_step") = 0.0f, py::arg("backend") = "", py::arg("sleep") = true,
          py::arg("ephemeral") = false, py::arg("editors") = py::list(), py::arg("shared") = false,
          py::arg("daemon") = 0, T,
          "A new world -> World. gravity None: (0, 0, -9.81); time_step 0: 1/60 s; backend\n"
          "'cpu', 'gpu', 'auto' or '' (the server's default); daemon: the daemon (server.id)\n"
          "to make it on, 0: in a domain of daemons the one with the fewest awake bodies.")
      .def(
          "list_worlds",
          [](PyClient& c, uint64_t daemon, OptS t) {
            pc::CallOptions o = callOptions(t);
            o.daemon = daemon;
            return request(c.box(), [&](pc::Client& cl) { return cl.listWorlds(o); });
          },
          py::kw_only(), py::arg("daemon") = 0, T,
          "Every world of the domain's daemons (daemon: only that one's) -> list of "
          "WorldSummary.")
      .def(
          "daemons",
          [](PyClient& c) { return quick(c.box(), [](pc::Client& cl) { return cl.daemons(); }); },
          "The daemons of the domain whose status is fresh -> list of DaemonInfo.")
      .def(
          "duplicate_replies",
          [](PyClient& c) {
            return quick(c.box(), [](pc::Client& cl) { return cl.duplicateReplies(); });
          },
          "Replies to requests already answered (a command two daemons took; 0 expected).")
      .def(
          "world", [](PyClient& c, uint32_t id) { return PyWorld(c.box(), id); }, py::arg("id"),
          "A World for an existing world's id (no request).")
      .def(
          "world_named",
          [](PyClient& c, const std::string& name, OptS t) {
            pc::WorldHandle h = blocking(
                c.box(), [&](pc::Client& cl) { return cl.worldNamed(name, callOptions(t)); });
            return PyWorld(c.box(), h.id());
          },
          py::arg("name"), py::kw_only(), T, "The world of that name (NotFound if none).")
      .def(
          "latest_status",
          [](PyClient& c) {
            return quick(c.box(), [](pc::Client& cl) { return cl.latestStatus(); });
          },
          "The newest phys/status sample (ServerStatus), or None.")
      .def(
          "recent_events",
          [](PyClient& c) {
            return quick(c.box(), [](pc::Client& cl) { return cl.recentEvents(); });
          },
          "The last (up to 64) events received, oldest first.")
      .def("on_event", &PyClient::onEvent, py::arg("callback"),
           "callback(event) on the SDK's thread for every event from now on (None: stop).")
      .def(
          "subscribe",
          [](PyClient& c, uint32_t world, const py::object& callback) {
            return PyWorld(c.box(), world).subscribe(callback, py::none(), py::none(), {});
          },
          py::arg("world"), py::arg("callback") = py::none(),
          py::return_value_policy::take_ownership, "World(world).subscribe(callback).")
      .def("__enter__", [](py::object self) { return self; })
      .def("__exit__", [](PyClient& c, py::args) { c.close(); });
}

}  // namespace

// ---------------------------------------------------------------------------------------------

PYBIND11_MODULE(physclient, m) {
  m.doc() =
      "physclient: the physd client SDK for Python (docs/PYTHON.md).\n\n"
      "Vectors are tuples (x, y, z); rotations are unit quaternions (x, y, z, w); body and\n"
      "joint ids are ints. Failed requests raise physclient.Error (a subclass per code).";
  m.attr("__version__") = PHYSCLIENT_VERSION;

  defineEnums(m);
  defineErrors(m);
  defineDefinitions(m);
  defineResults(m);
  defineWorldResults(m);
  defineSubscription(m);
  defineWorld(m);
  defineWorldMore(m);
  defineClient(m);

  // StateFrame as a sequence, asyncio, World as a context manager (issue 40).
  defineFrameSequence(m);
  defineAsync(m);
  defineWorldAsyncMore(m);
  defineClientAsync(m);
  defineWorldContext(m);

  // Clients still open at exit are closed before Python finalizes (their threads joined, so no
  // callback runs into a finalizing interpreter); then the asyncio Completer stops (what the
  // closing failed is dropped: no loop runs any more).
  py::module_::import("atexit").attr("register")(py::cpp_function([] {
    gExiting.store(true);
    closeAllClients();
    withoutGil([] { completer().stop(); });
  }));
}
