// Internal: a fixed-capacity ring buffer (no allocation after construction), for the estimator's queues.
#pragma once

#include <cstddef>
#include <vector>

namespace diekf {
namespace internal {

template <typename T>
class Ring {
 public:
  explicit Ring(size_t capacity) : data_(capacity) {}
  size_t size() const { return size_; }
  bool empty() const { return size_ == 0; }
  bool full() const { return size_ == data_.size(); }
  T& operator[](size_t i) { return data_[(head_ + i) % data_.size()]; }
  const T& operator[](size_t i) const { return data_[(head_ + i) % data_.size()]; }
  const T& back() const { return (*this)[size_ - 1]; }
  /// Appends; drops the oldest element when full.
  void push(const T& value) {
    if (full()) pop();
    data_[(head_ + size_) % data_.size()] = value;
    ++size_;
  }
  /// Slot for a new element at the back (caller fills it in place).
  T& emplaceSlot() {
    if (full()) pop();
    ++size_;
    return data_[(head_ + size_ - 1) % data_.size()];
  }
  void pop() {
    head_ = (head_ + 1) % data_.size();
    --size_;
  }
  void clear() { head_ = size_ = 0; }

 private:
  std::vector<T> data_;
  size_t head_ = 0, size_ = 0;
};

}  // namespace internal
}  // namespace diekf
