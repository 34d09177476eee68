#include "png_writer.hpp"

#include <array>
#include <cstdint>
#include <cstdio>
#include <vector>

namespace stillpoint::synth {
namespace {

// Slice-by-8 CRC-32 tables (table[0] is the classic bytewise one).
const std::array<std::array<std::uint32_t, 256>, 8>& crcTables() {
  static const auto tables = [] {
    std::array<std::array<std::uint32_t, 256>, 8> t{};
    for (std::uint32_t n = 0; n < 256; ++n) {
      std::uint32_t c = n;
      for (int k = 0; k < 8; ++k) c = (c & 1) ? 0xEDB88320u ^ (c >> 1) : c >> 1;
      t[0][n] = c;
    }
    for (std::uint32_t n = 0; n < 256; ++n) {
      for (std::size_t k = 1; k < 8; ++k) t[k][n] = (t[k - 1][n] >> 8) ^ t[0][t[k - 1][n] & 0xFF];
    }
    return t;
  }();
  return tables;
}

std::uint32_t crcUpdate(std::uint32_t crc, const std::uint8_t* data, std::size_t n) {
  const auto& t = crcTables();
  while (n >= 8) {
    const std::uint32_t lo = crc ^ (static_cast<std::uint32_t>(data[0]) | static_cast<std::uint32_t>(data[1]) << 8 |
                                    static_cast<std::uint32_t>(data[2]) << 16 | static_cast<std::uint32_t>(data[3]) << 24);
    crc = t[7][lo & 0xFF] ^ t[6][(lo >> 8) & 0xFF] ^ t[5][(lo >> 16) & 0xFF] ^ t[4][lo >> 24] ^ t[3][data[4]] ^
          t[2][data[5]] ^ t[1][data[6]] ^ t[0][data[7]];
    data += 8;
    n -= 8;
  }
  for (; n > 0; --n, ++data) crc = t[0][(crc ^ *data) & 0xFF] ^ (crc >> 8);
  return crc;
}

void put32(std::vector<std::uint8_t>* out, std::uint32_t v) {
  for (int s = 24; s >= 0; s -= 8) out->push_back(static_cast<std::uint8_t>(v >> s));
}

void chunk(std::vector<std::uint8_t>* out, const char* type, const std::uint8_t* data, std::size_t n) {
  put32(out, static_cast<std::uint32_t>(n));
  const std::size_t start = out->size();
  out->insert(out->end(), type, type + 4);
  out->insert(out->end(), data, data + n);
  const std::uint32_t crc = crcUpdate(0xFFFFFFFFu, out->data() + start, n + 4) ^ 0xFFFFFFFFu;
  put32(out, crc);
}

}  // namespace

Status writeStoredPng(const std::string& path, const cv::Mat& image) {
  int channels = 0, bit_depth = 8, colour_type = 0;
  if (image.type() == CV_8UC1) {
    channels = 1;
  } else if (image.type() == CV_8UC3) {
    channels = 3;
    colour_type = 2;
  } else if (image.type() == CV_16UC1) {
    channels = 1;
    bit_depth = 16;
  } else {
    return Error{"cannot write " + path + ": unsupported image type"};
  }
  const std::size_t w = static_cast<std::size_t>(image.cols), h = static_cast<std::size_t>(image.rows);
  const std::size_t row_bytes = w * channels * (bit_depth / 8);
  // Raw scanlines: filter byte 0, then big-endian samples (RGB order).
  std::vector<std::uint8_t> raw(h * (row_bytes + 1));
  for (std::size_t y = 0; y < h; ++y) {
    std::uint8_t* dst = raw.data() + y * (row_bytes + 1);
    *dst++ = 0;
    const std::uint8_t* src = image.ptr<std::uint8_t>(static_cast<int>(y));
    if (channels == 3) {
      for (std::size_t x = 0; x < w; ++x, src += 3, dst += 3) {
        dst[0] = src[2];
        dst[1] = src[1];
        dst[2] = src[0];
      }
    } else if (bit_depth == 16) {
      for (std::size_t x = 0; x < w; ++x, src += 2, dst += 2) {
        dst[0] = src[1];
        dst[1] = src[0];
      }
    } else {
      std::copy(src, src + row_bytes, dst);
    }
  }
  // zlib stream of stored blocks (<= 65535 bytes each) plus Adler-32.
  std::vector<std::uint8_t> z;
  z.reserve(raw.size() + raw.size() / 65535 * 5 + 16);
  z.push_back(0x78);
  z.push_back(0x01);
  std::uint32_t a = 1, b = 0;
  for (std::size_t off = 0; off < raw.size() || off == 0;) {
    const std::size_t n = std::min<std::size_t>(65535, raw.size() - off);
    const bool last = off + n == raw.size();
    z.push_back(last ? 1 : 0);
    z.push_back(static_cast<std::uint8_t>(n & 0xFF));
    z.push_back(static_cast<std::uint8_t>(n >> 8));
    z.push_back(static_cast<std::uint8_t>(~n & 0xFF));
    z.push_back(static_cast<std::uint8_t>((~n >> 8) & 0xFF));
    z.insert(z.end(), raw.begin() + static_cast<std::ptrdiff_t>(off), raw.begin() + static_cast<std::ptrdiff_t>(off + n));
    // Adler-32 in chunks short enough that the sums cannot overflow.
    for (std::size_t i = off; i < off + n;) {
      const std::size_t end = std::min(off + n, i + 5552);
      for (; i < end; ++i) {
        a += raw[i];
        b += a;
      }
      a %= 65521;
      b %= 65521;
    }
    off += n;
    if (last) break;
  }
  put32(&z, (b << 16) | a);

  std::vector<std::uint8_t> png = {0x89, 'P', 'N', 'G', '\r', '\n', 0x1A, '\n'};
  png.reserve(z.size() + 64);
  std::vector<std::uint8_t> ihdr;
  put32(&ihdr, static_cast<std::uint32_t>(w));
  put32(&ihdr, static_cast<std::uint32_t>(h));
  ihdr.insert(ihdr.end(), {static_cast<std::uint8_t>(bit_depth), static_cast<std::uint8_t>(colour_type), 0, 0, 0});
  chunk(&png, "IHDR", ihdr.data(), ihdr.size());
  chunk(&png, "IDAT", z.data(), z.size());
  chunk(&png, "IEND", nullptr, 0);
  std::FILE* f = std::fopen(path.c_str(), "wb");
  if (!f) return Error{"cannot write " + path};
  const bool ok = std::fwrite(png.data(), 1, png.size(), f) == png.size();
  if (std::fclose(f) != 0 || !ok) return Error{"cannot write " + path};
  return Status::success();
}

}  // namespace stillpoint::synth
