#include "rsfm/io/atomic_file.hpp"

#include <unistd.h>

#include <fstream>
#include <stdexcept>

namespace rsfm::io {
namespace fs = std::filesystem;

AtomicFileSet::~AtomicFileSet() {
  if (!done_) abort();
}

fs::path AtomicFileSet::temp(const fs::path& final_path) {
  fs::path t = final_path.parent_path() /
               (final_path.stem().string() + ".tmp" + std::to_string(::getpid()) +
                final_path.extension().string());
  files_.emplace_back(t, final_path);
  return t;
}

fs::path AtomicFileSet::write(const fs::path& final_path, const std::string& text) {
  const fs::path t = temp(final_path);
  std::ofstream f(t, std::ios::binary);
  f << text;
  f.close();
  if (!f) throw std::runtime_error("cannot write " + final_path.string());
  return t;
}

void AtomicFileSet::commit() {
  for (const auto& [t, final_path] : files_) {
    std::error_code ec;
    fs::rename(t, final_path, ec);
    if (ec) throw std::runtime_error("cannot move " + t.string() + " to " + final_path.string() +
                                     ": " + ec.message());
  }
  done_ = true;
}

void AtomicFileSet::abort() {
  for (const auto& [t, final_path] : files_) {
    std::error_code ec;
    fs::remove(t, ec);
  }
  files_.clear();
  done_ = true;
}

void writeAllOrNothing(const std::vector<std::pair<std::filesystem::path, std::string>>& files) {
  AtomicFileSet set;
  for (const auto& [path, text] : files) set.write(path, text);
  set.commit();
}

std::string ensureWritableDirectory(const fs::path& dir) {
  std::error_code ec;
  if (fs::exists(dir, ec) && !fs::is_directory(dir, ec))
    return "output path " + dir.string() + " exists and is not a directory";
  const bool existed = fs::exists(dir, ec);
  if (!existed) {
    fs::create_directories(dir, ec);
    if (ec) return "cannot create output directory " + dir.string() + ": " + ec.message();
  }
  const fs::path probe = dir / (".rsfm-write-test-" + std::to_string(::getpid()));
  {
    std::ofstream f(probe);
    if (!f) {
      if (!existed) fs::remove(dir, ec);
      return "output directory " + dir.string() + " is not writable";
    }
  }
  fs::remove(probe, ec);
  return {};
}

}  // namespace rsfm::io
