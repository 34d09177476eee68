#include "onnx_info.hpp"

#include <set>

namespace stillpoint::semantic {
namespace {

// Protobuf wire format: every field is a varint key (field << 3 | wire type)
// followed by a varint (0), 8 bytes (1), a length-delimited blob (2) or 4 bytes (5).
class Reader {
 public:
  Reader(const char* begin, const char* end) : p_(begin), end_(end) {}
  bool done() const { return p_ >= end_; }
  bool ok() const { return ok_; }

  bool varint(std::uint64_t* v) {
    *v = 0;
    for (int shift = 0; shift < 64 && p_ < end_; shift += 7) {
      const auto b = static_cast<std::uint8_t>(*p_++);
      *v |= std::uint64_t(b & 0x7f) << shift;
      if (!(b & 0x80)) return true;
    }
    return ok_ = false;
  }
  // Next field: its number, wire type and (for length-delimited) its bytes.
  bool next(int* field, int* wire, Reader* sub, std::uint64_t* value) {
    std::uint64_t key;
    if (!varint(&key)) return false;
    *field = int(key >> 3);
    *wire = int(key & 7);
    switch (*wire) {
      case 0:
        return varint(value);
      case 1:
        return skip(8);
      case 5:
        return skip(4);
      case 2: {
        std::uint64_t len;
        if (!varint(&len) || len > std::uint64_t(end_ - p_)) return ok_ = false;
        *sub = Reader(p_, p_ + len);
        p_ += len;
        return true;
      }
      default:
        return ok_ = false;
    }
  }
  std::string str() const { return std::string(p_, end_); }

 private:
  bool skip(std::size_t n) {
    if (std::size_t(end_ - p_) < n) return ok_ = false;
    p_ += n;
    return true;
  }
  const char* p_;
  const char* end_;
  bool ok_ = true;
};

// ValueInfoProto{name=1, type=2}; TypeProto{tensor_type=1}; Tensor{shape=2};
// TensorShapeProto{dim=1}; Dimension{dim_value=1, dim_param=2}.
bool parseValueInfo(Reader r, OnnxTensorInfo* out) {
  int f, w;
  Reader sub(nullptr, nullptr);
  std::uint64_t v;
  while (!r.done()) {
    if (!r.next(&f, &w, &sub, &v)) return false;
    if (w != 2) continue;
    if (f == 1) out->name = sub.str();
    if (f != 2) continue;
    Reader type = sub;
    while (!type.done()) {
      if (!type.next(&f, &w, &sub, &v)) return false;
      if (f != 1 || w != 2) continue;
      Reader tensor = sub;
      while (!tensor.done()) {
        if (!tensor.next(&f, &w, &sub, &v)) return false;
        if (f != 2 || w != 2) continue;
        Reader shape = sub;
        while (!shape.done()) {
          if (!shape.next(&f, &w, &sub, &v)) return false;
          if (f != 1 || w != 2) continue;
          Reader dim = sub;
          std::int64_t value = -1;
          Reader s2(nullptr, nullptr);
          while (!dim.done()) {
            if (!dim.next(&f, &w, &s2, &v)) return false;
            if (f == 1 && w == 0) value = std::int64_t(v);
          }
          out->dims.push_back(value > 0 ? value : -1);
        }
      }
    }
  }
  return r.ok();
}

}  // namespace

Result<std::vector<OnnxTensorInfo>> parseOnnxInputs(const std::string& bytes) {
  Reader model(bytes.data(), bytes.data() + bytes.size());
  int f, w;
  Reader sub(nullptr, nullptr);
  std::uint64_t v;
  std::vector<OnnxTensorInfo> inputs;
  std::set<std::string> initializers;
  bool have_graph = false;
  while (!model.done()) {
    if (!model.next(&f, &w, &sub, &v)) return Error{"not a valid ONNX (protobuf) file"};
    if (f != 7 || w != 2) continue;  // ModelProto.graph
    have_graph = true;
    Reader graph = sub;
    while (!graph.done()) {
      if (!graph.next(&f, &w, &sub, &v)) return Error{"not a valid ONNX (protobuf) file"};
      if (w != 2) continue;
      if (f == 11) {  // GraphProto.input
        OnnxTensorInfo info;
        if (!parseValueInfo(sub, &info)) return Error{"not a valid ONNX file (bad graph input)"};
        inputs.push_back(std::move(info));
      } else if (f == 5) {  // GraphProto.initializer: TensorProto.name = 8
        Reader tensor = sub;
        Reader name(nullptr, nullptr);
        while (!tensor.done()) {
          if (!tensor.next(&f, &w, &name, &v)) return Error{"not a valid ONNX file (bad initializer)"};
          if (f == 8 && w == 2) initializers.insert(name.str());
        }
      }
    }
  }
  if (!have_graph) return Error{"not an ONNX model (no graph)"};
  std::vector<OnnxTensorInfo> real;
  for (auto& in : inputs)
    if (!initializers.count(in.name)) real.push_back(std::move(in));
  if (real.empty()) return Error{"ONNX graph declares no input"};
  return real;
}

}  // namespace stillpoint::semantic
