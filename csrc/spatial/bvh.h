// A bounding volume hierarchy over triangles, in float64: closest points on the
// mesh and ray hits (first, any, all).
//
// One include for all of it: bvh_triangle.h (the exact point-triangle and ray-triangle
// primitives), bvh_tree.h (the tree, its build and its traversal layout), bvh_closest.h
// (closest points) and bvh_rays.h (ray hits and crossings).
#pragma once

#include "spatial/bvh_closest.h"
#include "spatial/bvh_rays.h"
#include "spatial/bvh_tree.h"
#include "spatial/bvh_triangle.h"
