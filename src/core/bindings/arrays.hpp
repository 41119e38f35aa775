// What the bindings share about arrays: numpy arrays taken as they are (no conversion) and checked
// by hand for dtype and shape, raising ValueError with the argument's name; numpy arrays made from
// the core's outputs.
#pragma once

#include <nanobind/nanobind.h>
#include <nanobind/ndarray.h>

#include <array>
#include <cmath>
#include <cstdint>
#include <initializer_list>
#include <limits>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "tracer.hpp"

namespace thurston::bindings {

namespace nb = nanobind;

// Any CPU array; dtype and shape are checked by hand to raise ValueError with a clear message.
using Array = nb::ndarray<nb::ro, nb::device::cpu>;

inline std::string dtype_name(nb::dlpack::dtype dt) {
  const char* kind = "unknown";
  switch (nb::dlpack::dtype_code(dt.code)) {
    case nb::dlpack::dtype_code::Int:
      kind = "int";
      break;
    case nb::dlpack::dtype_code::UInt:
      kind = "uint";
      break;
    case nb::dlpack::dtype_code::Float:
      kind = "float";
      break;
    case nb::dlpack::dtype_code::Bool:
      return "bool";
    default:
      break;
  }
  return kind + std::to_string(int(dt.bits));
}

template <class T>
const char* type_name();
template <>
inline const char* type_name<double>() {
  return "float64";
}
template <>
inline const char* type_name<float>() {
  return "float32";
}
template <>
inline const char* type_name<std::int32_t>() {
  return "int32";
}
template <>
inline const char* type_name<std::int64_t>() {
  return "int64";
}

using OptionalArray = std::optional<Array>;

inline std::string shape_text(const Array& a) {
  std::string s = "(";
  for (std::size_t d = 0; d < a.ndim(); ++d) s += (d ? ", " : "") + std::to_string(a.shape(d));
  return s + (a.ndim() == 1 ? ",)" : ")");
}

// Checks dtype and shape; -1 in `shape` matches any length. `expected` names the shape for errors.
template <class T>
void check(const Array& a, const char* name, std::initializer_list<std::int64_t> shape,
           const char* expected) {
  if (a.dtype() != nb::dtype<T>())
    throw nb::value_error((std::string(name) + " must have dtype " + type_name<T>() + ", got " +
                           dtype_name(a.dtype()))
                              .c_str());
  bool ok = a.ndim() == shape.size();
  std::size_t d = 0;
  for (std::int64_t n : shape) {
    if (ok && n >= 0 && std::int64_t(a.shape(d)) != n) ok = false;
    ++d;
  }
  if (!ok)
    throw nb::value_error(
        (std::string(name) + " must have shape " + expected + ", got " + shape_text(a)).c_str());
}

template <class T>
Strided2<T> view2(const Array& a) {
  return {static_cast<const T*>(a.data()), a.stride(0), a.ndim() > 1 ? a.stride(1) : 0};
}

template <class T, std::size_t C>
std::vector<std::array<T, C>> rows(const Array& a) {
  const Strided2<T> v = view2<T>(a);
  std::vector<std::array<T, C>> out(a.shape(0));
  for (std::size_t i = 0; i < out.size(); ++i)
    for (std::size_t j = 0; j < C; ++j) out[i][j] = v(i, j);
  return out;
}

inline std::vector<std::int32_t> indices(const Array& a, std::int64_t bound, const char* name,
                                         const char* bound_name) {
  const Strided2<std::int32_t> v = view2<std::int32_t>(a);
  std::vector<std::int32_t> out(a.shape(0));
  for (std::size_t i = 0; i < out.size(); ++i) {
    out[i] = v(i, 0);
    if (out[i] < 0 || out[i] >= bound)
      throw nb::value_error((std::string(name) + " has index " + std::to_string(out[i]) +
                             " at row " + std::to_string(i) + ", outside [0, " + bound_name +
                             " = " + std::to_string(bound) + ")")
                                .c_str());
  }
  return out;
}

template <class T, std::size_t C>
void require_finite(const std::vector<std::array<T, C>>& rows, const char* name) {
  for (std::size_t i = 0; i < rows.size(); ++i)
    for (T x : rows[i])
      if (!std::isfinite(x))
        throw nb::value_error(
            (std::string(name) + " contain NaN or inf at row " + std::to_string(i)).c_str());
}

// Embree holds vertices and instance maps as float: a finite double beyond float's range would
// become inf there.
inline bool fits_float(double x) {
  return std::isfinite(x) && std::fabs(x) <= double(std::numeric_limits<float>::max());
}

template <std::size_t C>
void require_float_range(const std::vector<std::array<double, C>>& rows, const char* name) {
  for (std::size_t i = 0; i < rows.size(); ++i)
    for (double x : rows[i])
      if (!fits_float(x))
        throw nb::value_error((std::string(name) + " row " + std::to_string(i) +
                               " is beyond the range of float32, which Embree keeps it in")
                                  .c_str());
}

// A numpy array that owns `data` (allocated with new[]).
template <class T>
nb::object to_numpy(std::unique_ptr<T[]> data, std::initializer_list<std::size_t> shape) {
  T* raw = data.get();
  nb::capsule owner(raw, [](void* p) noexcept { delete[] static_cast<T*>(p); });
  data.release();
  return nb::cast(nb::ndarray<nb::numpy, T>(raw, shape, owner));
}

inline void check_rays(const Array& a, const Array& b, const char* a_name, const char* b_name,
                       std::int64_t width, const char* what) {
  const std::string shape = width == 4 ? "(N,4)" : "(N,3)";
  check<double>(a, a_name, {-1, width}, shape.c_str());
  check<double>(b, b_name, {std::int64_t(a.shape(0)), width},
                (shape + " with N = len(" + a_name + ")").c_str());
  const Strided2<double> va = view2<double>(a), vb = view2<double>(b);
  for (std::size_t i = 0; i < a.shape(0); ++i)
    for (std::int64_t j = 0; j < width; ++j)
      if (!std::isfinite(va(i, j)) || !std::isfinite(vb(i, j)))
        throw nb::value_error((std::string(what) + " " + std::to_string(i) + " has a non-finite " +
                               (width == 4 ? "origin or direction" : "start or end"))
                                  .c_str());
}

}  // namespace thurston::bindings
