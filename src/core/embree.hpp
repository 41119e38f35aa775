// The one place that knows about Embree 3 versus Embree 4.
#pragma once

#if THURSTON_EMBREE_MAJOR >= 4
#include <embree4/rtcore.h>
#else
#include <embree3/rtcore.h>
#endif
RTC_NAMESPACE_USE  // for Embree builds with an API namespace
#include <stdexcept>
#include <string>

#include "vec.hpp"

    namespace thurston::embree {

  // A ray over the chord org + u * dir, u in [tnear, tfar].
  inline RTCRay make_ray(const float org[3], const float dir[3], float tnear, float tfar) {
    RTCRay ray{};
    ray.org_x = org[0];
    ray.org_y = org[1];
    ray.org_z = org[2];
    ray.dir_x = dir[0];
    ray.dir_y = dir[1];
    ray.dir_z = dir[2];
    ray.tnear = tnear;
    ray.tfar = tfar;
    ray.time = 0.0f;
    ray.mask = 0xFFFFFFFFu;
    ray.id = 0;
    ray.flags = 0;
    return ray;
  }

  // The ray over the chart chord from x0 to x1 (u in [tnear, 1]), in Embree's float.
  inline RTCRay chord_ray(const Vec3& x0, const Vec3& x1, float tnear) {
    const float org[3] = {float(x0[0]), float(x0[1]), float(x0[2])};
    const float dir[3] = {float(x1[0] - x0[0]), float(x1[1] - x0[1]), float(x1[2] - x0[2])};
    return make_ray(org, dir, tnear, 1.0f);
  }

  // Raises the device's error, if it has one, as saying that Embree failed to do `what`.
  inline void check_device(RTCDevice device, const char* what) {
    const RTCError error = rtcGetDeviceError(device);
    if (error != RTC_ERROR_NONE)
      throw std::runtime_error(std::string("Embree failed to ") + what + " (error " +
                               std::to_string(int(error)) + ")");
  }

  // The first hit on a chord of a two-level scene whose top-level geometry IDs number the
  // instances: the instance (the instance geometry hit, or the geometry hit where it is attached
  // directly), the primitive in its geometry and the chord parameter.
  struct FirstHit {
    int prim = -1;  // -1: no hit
    unsigned instance = 0;
    float u = 0.0f;
  };

  inline FirstHit intersect(RTCScene scene, const RTCRay& ray) {
    RTCRayHit rayhit{};
    rayhit.ray = ray;
    rayhit.hit.geomID = RTC_INVALID_GEOMETRY_ID;
    rayhit.hit.instID[0] = RTC_INVALID_GEOMETRY_ID;
#if RTC_VERSION_MAJOR >= 4
    RTCIntersectArguments args;
    rtcInitIntersectArguments(&args);
    rtcIntersect1(scene, &rayhit, &args);
#else
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    rtcIntersect1(scene, &context, &rayhit);
#endif
    FirstHit hit;
    if (rayhit.hit.geomID == RTC_INVALID_GEOMETRY_ID) return hit;
    hit.prim = static_cast<int>(rayhit.hit.primID);
    hit.instance =
        rayhit.hit.instID[0] != RTC_INVALID_GEOMETRY_ID ? rayhit.hit.instID[0] : rayhit.hit.geomID;
    hit.u = rayhit.ray.tfar;
    return hit;
  }

  // Whether anything lies on the chord.
  inline bool occluded(RTCScene scene, RTCRay ray) {
#if RTC_VERSION_MAJOR >= 4
    RTCOccludedArguments args;
    rtcInitOccludedArguments(&args);
    rtcOccluded1(scene, &ray, &args);
#else
    RTCIntersectContext context;
    rtcInitIntersectContext(&context);
    rtcOccluded1(scene, &context, &ray);
#endif
    // Embree marks an occluded ray by setting tfar to -inf.
    return ray.tfar < 0.0f;
  }

}  // namespace thurston::embree
