// Error reporting of the FFI handlers. Every handler runs all of its work,
// validation and allocation included, inside `guarded`, which turns any
// exception into an ffi::Error of the matching category, so no exception ever
// crosses the FFI boundary:
//
//   std::bad_alloc, std::length_error -> RESOURCE_EXHAUSTED "voxax: out of memory in ..."
//   InvalidInput                      -> INVALID_ARGUMENT with the exception's message
//   any other exception               -> INTERNAL "voxax: internal error in ...: <what()>"
#pragma once

#include <exception>
#include <new>
#include <stdexcept>
#include <string>

#include "xla/ffi/api/ffi.h"

namespace voxax {

namespace ffi = xla::ffi;

// Thrown by kernel code (worker threads included) that finds invalid input
// while it works; reported as an invalid argument with this message.
class InvalidInput : public std::runtime_error {
 public:
  using std::runtime_error::runtime_error;
};

inline ffi::Error out_of_memory(const char* where) {
  return ffi::Error(ffi::ErrorCode::kResourceExhausted,
                    std::string("voxax: out of memory in ") + where);
}

namespace detail {

inline ffi::Error current_exception_error(const char* where) {
  try {
    throw;
  } catch (const std::bad_alloc&) {
    return out_of_memory(where);
  } catch (const std::length_error&) {
    // A container asked for more elements than it can address.
    return out_of_memory(where);
  } catch (const InvalidInput& e) {
    return ffi::Error::InvalidArgument(e.what());
  } catch (const std::exception& e) {
    return ffi::Error::Internal(std::string("voxax: internal error in ") + where + ": " + e.what());
  } catch (...) {
    return ffi::Error::Internal(std::string("voxax: internal error in ") + where +
                                ": unknown exception");
  }
}

}  // namespace detail

// Runs body(), which returns an ffi::Error, and reports any exception it
// throws as an error; `where` names the kernel in messages.
template <typename Body>
ffi::Error guarded(const char* where, Body&& body) noexcept {
  try {
    try {
      return body();
    } catch (...) {
      return detail::current_exception_error(where);
    }
  } catch (...) {
    // Building the message failed too (memory is exhausted): an error without
    // a message needs no allocation.
    return ffi::Error(ffi::ErrorCode::kResourceExhausted, std::string());
  }
}

}  // namespace voxax
