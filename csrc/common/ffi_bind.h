// FFI bindings in one line: a handler's binding is read off its C++ signature
// (XLA_FFI_DEFINE_HANDLER_SYMBOL(symbol, impl) with no explicit binding), so the argument
// list is written once, in the handler itself. Buffers are arguments, results are
// results, `ffi::ThreadPool` is the host thread pool (made bindable here) and attributes
// are `ffi::Attr<T, name>` with a name declared as `constexpr char kName[] = "name";`.
// `buffers_binding<kArgs, kRets>()` is the explicit form for handlers whose attributes are
// added by a helper (the grid attributes of the voxelization kernels).
#pragma once

#include <utility>

#include "xla/ffi/api/ffi.h"

namespace xla::ffi {

// The host thread pool, as a context parameter of an automatically bound handler.
template <>
struct CtxBinding<ThreadPool> {
  using Ctx = ThreadPool;
};

}  // namespace xla::ffi

namespace voxax {

// Appends `kArgs` untyped argument buffers, then `kRets >= 1` untyped results. (A binding
// cannot be moved outside the FFI's own code, so each step takes the previous one by
// reference and returns a new one.)
template <int kArgs, int kRets, typename Binding>
auto add_buffers(Binding&& binding) {
  static_assert(kRets >= 1, "a handler has at least one result");
  if constexpr (kArgs > 0)
    return add_buffers<kArgs - 1, kRets>(std::move(binding).template Arg<xla::ffi::AnyBuffer>());
  else if constexpr (kRets > 1)
    return add_buffers<0, kRets - 1>(std::move(binding).template Ret<xla::ffi::AnyBuffer>());
  else
    return std::move(binding).template Ret<xla::ffi::AnyBuffer>();
}

// The thread pool, then `kArgs` untyped argument buffers, then `kRets` untyped results.
template <int kArgs, int kRets>
auto buffers_binding() {
  return add_buffers<kArgs, kRets>(xla::ffi::Ffi::Bind().Ctx<xla::ffi::ThreadPool>());
}

}  // namespace voxax

// Defines and exports the C symbol of an FFI handler (the library hides every other
// symbol). Use it inside `namespace voxax`, after the handler's anonymous namespace.
#define VOXAX_FFI_HANDLER(symbol, ...)                                                        \
  _Pragma("GCC visibility push(default)") XLA_FFI_DEFINE_HANDLER_SYMBOL(symbol, __VA_ARGS__); \
  _Pragma("GCC visibility pop")
