// A table of a homogeneous geometry's exponential map at the origin, exp_O(w) for the tangent
// vectors w of a ball (the chart at the origin orthonormal), as seeds for shooting: every
// geodesic from the origin to a point T no longer than the ball's radius starts at some w of the
// ball, and the table's cells are small enough that exp_O is close to linear on each: T then lies
// in (or within a margin of) the image of a cell's linear interpolation, whose preimage of T is
// close to w.
//
// The ball is cut into cells by a cube-sphere of directions (6 faces, n x n each) times m shells,
// each cell split into 6 tetrahedra along its main diagonal (a conforming split within a face);
// a bounding volume hierarchy over the boxes of the cells' images finds the cells whose image
// may hold T.
#pragma once

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <vector>

#include "vec.hpp"

namespace thurston {

class ExpTable {
 public:
  // exp_O over the ball of the given radius, about `cell` long per cell at its rim (fewer cells
  // where that would need more than max_cells); flow(direction, radii, images) fills the images
  // exp_O(r d) of one unit direction d at the radii given (increasing).
  template <class Flow>
  ExpTable(double radius, double cell, std::size_t max_cells, Flow&& flow) : radius_(radius) {
    const double quarter = 0.5 * kPi;  // a face's angular width
    n_ = std::max(1, int(std::ceil(radius * quarter / cell)));
    m_ = std::max(1, int(std::ceil(radius / cell)));
    while (std::size_t(6) * n_ * n_ * m_ > max_cells && (n_ > 1 || m_ > 1)) {
      n_ = std::max(1, int(n_ * 0.9));
      m_ = std::max(1, int(m_ * 0.9));
    }
    cell_ = std::max(radius * quarter / n_, radius / m_);
    std::vector<double> radii(m_ + 1);
    for (int k = 0; k <= m_; ++k) radii[k] = radius * k / m_;
    directions_.resize(std::size_t(6) * (n_ + 1) * (n_ + 1));
    images_.resize(directions_.size() * (m_ + 1));
    std::vector<Vec3> along(m_ + 1);
    for (int f = 0; f < 6; ++f)
      for (int i = 0; i <= n_; ++i)
        for (int j = 0; j <= n_; ++j) {
          const std::size_t d = direction_index(f, i, j);
          directions_[d] = cube_sphere(f, i, j);
          flow(directions_[d], radii, along);
          for (int k = 0; k <= m_; ++k) images_[d * (m_ + 1) + k] = along[k];
        }
    build_hierarchy();
  }

  double radius() const { return radius_; }
  // The cells' size in w at the ball's rim.
  double cell() const { return cell_; }

  // A tangent vector w whose image under a cell's linear interpolation is the target, and the
  // inverse of that interpolation's linear part (an approximate inverse of d exp_O there).
  struct Seed {
    Vec3 w;
    std::array<Vec3, 3> inverse;  // rows
  };
  // The seeds of T (each at most `margin` outside its tetrahedron in barycentric coordinates),
  // appended to seeds.
  void seeds(const Vec3& T, double margin, std::vector<Seed>& seeds) const {
    if (nodes_.empty()) return;
    std::array<std::uint32_t, 64> stack;
    int top = 0;
    stack[top++] = 0;
    while (top > 0) {
      const Node& node = nodes_[stack[--top]];
      if (!node.holds(T)) continue;
      if (node.count > 0) {
        for (std::uint32_t c = node.first; c < node.first + node.count; ++c)
          cell_seeds(cells_[c], T, margin, seeds);
      } else if (top + 2 <= int(stack.size())) {
        stack[top++] = node.first;
        stack[top++] = node.first + 1;
      }
    }
  }

 private:
  struct Box {
    Vec3 lo{kInf, kInf, kInf}, hi{-kInf, -kInf, -kInf};
    void add(const Vec3& x) {
      for (int a = 0; a < 3; ++a) {
        lo[a] = std::min(lo[a], x[a]);
        hi[a] = std::max(hi[a], x[a]);
      }
    }
    void add(const Box& b) {
      add(b.lo);
      add(b.hi);
    }
    bool holds(const Vec3& x) const {
      for (int a = 0; a < 3; ++a)
        if (!(x[a] >= lo[a] && x[a] <= hi[a])) return false;
      return true;
    }
  };
  // A cell: face f, direction (i, j) to (i + 1, j + 1), shells k to k + 1; the box of its image.
  struct Cell {
    Box box;
    std::uint16_t f, i, j, k;
  };
  struct Node : Box {
    // leaves: cells [first, first + count); inner nodes (count 0): children first, first + 1
    std::uint32_t first = 0, count = 0;
  };

  std::size_t direction_index(int f, int i, int j) const {
    return (std::size_t(f) * (n_ + 1) + std::size_t(i)) * (n_ + 1) + std::size_t(j);
  }
  // The unit direction of node (i, j) of cube face f (equal angles along each axis of the face).
  Vec3 cube_sphere(int f, int i, int j) const {
    const double u = std::tan(0.25 * kPi * (2.0 * i / n_ - 1.0));
    const double v = std::tan(0.25 * kPi * (2.0 * j / n_ - 1.0));
    const double s = f % 2 == 0 ? 1.0 : -1.0;
    Vec3 p;
    switch (f / 2) {
      case 0:
        p = {s, u, v};
        break;
      case 1:
        p = {v, s, u};
        break;
      default:
        p = {u, v, s};
        break;
    }
    return scaled3(1.0 / norm3(p), p);
  }
  // Corner c (bits: i, j, k) of a cell: its w and image.
  void corner(const Cell& cell, int c, Vec3& w, Vec3& x) const {
    const int k = cell.k + ((c >> 2) & 1);
    const std::size_t d = direction_index(cell.f, cell.i + (c & 1), cell.j + ((c >> 1) & 1));
    w = scaled3(radius_ * k / m_, directions_[d]);
    x = images_[d * (m_ + 1) + k];
  }

  void cell_seeds(const Cell& cell, const Vec3& T, double margin, std::vector<Seed>& seeds) const {
    std::array<Vec3, 8> w, x;
    for (int c = 0; c < 8; ++c) corner(cell, c, w[c], x[c]);
    // the 6 tetrahedra of the cell's split along its diagonal 0 -> 7, one per order of the axes
    static constexpr int kOrders[6][3] = {{1, 2, 4}, {1, 4, 2}, {2, 1, 4},
                                          {2, 4, 1}, {4, 1, 2}, {4, 2, 1}};
    for (const auto& order : kOrders) {
      const std::array<int, 3> v{order[0], order[0] | order[1], 7};
      // the edges from corner 0 as columns: image X, tangent W; the interpolation is W X^-1
      const Vec3 dx[3] = {sub3(x[v[0]], x[0]), sub3(x[v[1]], x[0]), sub3(x[v[2]], x[0])};
      const double det = dot3(dx[0], cross3(dx[1], dx[2]));
      if (!(std::abs(det) > 1e-13 * norm3(dx[0]) * norm3(dx[1]) * norm3(dx[2])))
        continue;  // degenerate
      // rows of X^-1: the cross products of its columns over the determinant
      const Vec3 rows[3] = {scaled3(1.0 / det, cross3(dx[1], dx[2])),
                            scaled3(1.0 / det, cross3(dx[2], dx[0])),
                            scaled3(1.0 / det, cross3(dx[0], dx[1]))};
      const Vec3 d = sub3(T, x[0]);
      const Vec3 mu{dot3(rows[0], d), dot3(rows[1], d), dot3(rows[2], d)};
      const double first = 1.0 - mu[0] - mu[1] - mu[2];
      if (!(std::min({first, mu[0], mu[1], mu[2]}) >= -margin)) continue;
      Seed seed{w[0], {}};
      for (int e = 0; e < 3; ++e) {
        const Vec3 dw = sub3(w[v[e]], w[0]);
        seed.w = add3(seed.w, scaled3(mu[e], dw));
        for (int r = 0; r < 3; ++r)
          seed.inverse[r] = add3(seed.inverse[r], scaled3(dw[r], rows[e]));
      }
      seeds.push_back(seed);
    }
  }

  void build_hierarchy() {
    for (int f = 0; f < 6; ++f)
      for (int i = 0; i < n_; ++i)
        for (int j = 0; j < n_; ++j)
          for (int k = 0; k < m_; ++k) {
            Cell cell{{}, std::uint16_t(f), std::uint16_t(i), std::uint16_t(j), std::uint16_t(k)};
            for (int c = 0; c < 8; ++c) {
              Vec3 w, x;
              corner(cell, c, w, x);
              cell.box.add(x);
            }
            // the margin of seeds(): a point just outside a tetrahedron is still found
            for (int a = 0; a < 3; ++a) {
              const double pad = 0.05 * (cell.box.hi[a] - cell.box.lo[a]) + 1e-12;
              cell.box.lo[a] -= pad;
              cell.box.hi[a] += pad;
            }
            if (std::isfinite(cell.box.lo[0] + cell.box.lo[1] + cell.box.lo[2] + cell.box.hi[0] +
                              cell.box.hi[1] + cell.box.hi[2]))
              cells_.push_back(cell);
          }
    if (cells_.empty()) return;
    nodes_.reserve(2 * cells_.size() / kLeaf + 2);
    nodes_.emplace_back();
    split(0, 0, std::uint32_t(cells_.size()), 0);
  }
  // Node `at` over cells [first, last): split at the median of the longest axis of their centres.
  void split(std::size_t at, std::uint32_t first, std::uint32_t last, int depth) {
    Box box, centres;
    for (std::uint32_t c = first; c < last; ++c) {
      box.add(cells_[c].box);
      centres.add(scaled3(0.5, add3(cells_[c].box.lo, cells_[c].box.hi)));
    }
    static_cast<Box&>(nodes_[at]) = box;
    if (last - first <= kLeaf || depth >= 60) {
      nodes_[at].first = first;
      nodes_[at].count = last - first;
      return;
    }
    int axis = 0;
    for (int a = 1; a < 3; ++a)
      if (centres.hi[a] - centres.lo[a] > centres.hi[axis] - centres.lo[axis]) axis = a;
    const std::uint32_t middle = first + (last - first) / 2;
    std::nth_element(cells_.begin() + first, cells_.begin() + middle, cells_.begin() + last,
                     [axis](const Cell& a, const Cell& b) {
                       return a.box.lo[axis] + a.box.hi[axis] < b.box.lo[axis] + b.box.hi[axis];
                     });
    const std::size_t children = nodes_.size();
    nodes_[at].first = std::uint32_t(children);
    nodes_.emplace_back();
    nodes_.emplace_back();
    split(children, first, middle, depth + 1);
    split(children + 1, middle, last, depth + 1);
  }

  static constexpr std::uint32_t kLeaf = 4;
  double radius_, cell_ = 0.0;
  int n_ = 1, m_ = 1;
  std::vector<Vec3> directions_;  // per cube-sphere node
  std::vector<Vec3> images_;      // per node and shell: exp_O(r_k d)
  std::vector<Cell> cells_;
  std::vector<Node> nodes_;
};

}  // namespace thurston
