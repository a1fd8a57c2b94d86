#pragma once
// Private: a static-topology AABB tree (built once by median splits, refit every step).

#include <Eigen/Geometry>
#include <algorithm>
#include <array>
#include <vector>

namespace tactus::sim::detail {

class AabbTree {
 public:
  struct Node {
    Eigen::AlignedBox3d box;
    int left = -1;     ///< child indices (> this node's index), -1 for a leaf
    int right = -1;
    int first = 0;     ///< leaf: primitives order_[first, first + count)
    int count = 0;
  };

  /// Builds the topology from the primitive boxes (median split of the centroids along the
  /// longest axis; ties broken by index, so the tree is deterministic).
  void build(const std::vector<Eigen::AlignedBox3d>& boxes, int leaf_size = 4) {
    nodes_.clear();
    order_.resize(boxes.size());
    for (int i = 0; i < static_cast<int>(boxes.size()); ++i) order_[i] = i;
    leaf_size_ = std::max(1, leaf_size);
    if (boxes.empty()) return;
    nodes_.reserve(2 * boxes.size() / leaf_size_ + 2);
    buildNode(boxes, 0, static_cast<int>(boxes.size()));
    refit(boxes);
  }

  /// Recomputes every node box from the primitive boxes, bottom-up (children follow parents).
  void refit(const std::vector<Eigen::AlignedBox3d>& boxes) {
    for (int i = static_cast<int>(nodes_.size()) - 1; i >= 0; --i) {
      Node& node = nodes_[i];
      if (node.left < 0) {
        node.box.setEmpty();
        for (int k = node.first; k < node.first + node.count; ++k) node.box.extend(boxes[order_[k]]);
      } else {
        node.box = nodes_[node.left].box.merged(nodes_[node.right].box);
      }
    }
  }

  /// Calls visit(primitive) for every primitive in a leaf whose box passes `test(box)`.
  template <class Test, class Visit>
  void query(Test&& test, Visit&& visit) const {
    if (nodes_.empty()) return;
    std::array<int, 128> stack;
    int top = 0;
    stack[top++] = 0;
    while (top > 0) {
      const Node& node = nodes_[stack[--top]];
      if (!test(node.box)) continue;
      if (node.left < 0) {
        for (int k = node.first; k < node.first + node.count; ++k) visit(order_[k]);
      } else if (top + 2 <= static_cast<int>(stack.size())) {
        stack[top++] = node.right;
        stack[top++] = node.left;
      }
    }
  }

  int nodeCount() const { return static_cast<int>(nodes_.size()); }

 private:
  int buildNode(const std::vector<Eigen::AlignedBox3d>& boxes, int first, int last) {
    const int index = static_cast<int>(nodes_.size());
    nodes_.emplace_back();
    if (last - first <= leaf_size_) {
      nodes_[index].first = first;
      nodes_[index].count = last - first;
      return index;
    }
    // split the centroids at the median along the longest axis of their bounds
    Eigen::AlignedBox3d centroids;
    centroids.setEmpty();
    for (int k = first; k < last; ++k) centroids.extend(boxes[order_[k]].center());
    int axis = 0;
    centroids.sizes().maxCoeff(&axis);
    const int mid = first + (last - first) / 2;
    std::nth_element(order_.begin() + first, order_.begin() + mid, order_.begin() + last,
                     [&](int a, int b) {
                       const double ca = boxes[a].center()[axis];
                       const double cb = boxes[b].center()[axis];
                       return ca < cb || (ca == cb && a < b);
                     });
    const int left = buildNode(boxes, first, mid);
    const int right = buildNode(boxes, mid, last);
    nodes_[index].left = left;
    nodes_[index].right = right;
    return index;
  }

  std::vector<Node> nodes_;
  std::vector<int> order_;
  int leaf_size_ = 4;
};

}  // namespace tactus::sim::detail
