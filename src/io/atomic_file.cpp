#include "rsfm/io/atomic_file.hpp"

#include "rsfm/io/input_error.hpp"

#include <dirent.h>
#include <fcntl.h>
#include <fmt/format.h>
#include <signal.h>
#include <stdio.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstring>
#include <mutex>
#include <random>
#include <stdexcept>
#include <system_error>

namespace rsfm::io {
namespace fs = std::filesystem;

namespace {

/// A new file `dir/stem.tmp-XXXXXX.ext` created with O_EXCL | O_NOFOLLOW (never an existing
/// file or a planted link); returns its path and the open descriptor.
std::pair<fs::path, int> createTemp(const fs::path& final_path) {
  static thread_local std::mt19937_64 rng(std::random_device{}() ^ (static_cast<unsigned long long>(::getpid()) << 32));
  static const char* alphabet = "abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789";
  for (int attempt = 0; attempt < 100; ++attempt) {
    std::string tag;
    for (int i = 0; i < 10; ++i) tag += alphabet[rng() % 62];
    const fs::path t = final_path.parent_path() / (final_path.stem().string() + ".tmp-" + tag + final_path.extension().string());
    const int fd = ::open(t.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0644);
    if (fd >= 0) return {t, fd};
    if (errno != EEXIST) throw std::runtime_error(fmt::format("cannot create a file in {}: {}", final_path.parent_path().string(), std::strerror(errno)));
  }
  throw std::runtime_error("cannot create a temporary file beside " + final_path.string());
}

/// ".NAME" + suffix for the directory `dir` (built step by step: GCC 12's -Wrestrict misfires on
/// "." + string + "...").
std::string hiddenName(const fs::path& dir, const char* suffix) {
  std::string s(1, '.');
  s.append(dir.filename().string());
  s.append(suffix);
  return s;
}

// ---- The signal handler's list of staging directories (async-signal-safe cleanup) ----------
constexpr int kSlots = 8;
constexpr int kMaxParents = 8;
constexpr std::size_t kPathBytes = 4096;
struct Slot {
  std::atomic<bool> used{false};   // claimed by an OutputDir
  std::atomic<bool> ready{false};  // its paths are complete: only then may the handler use them
  char staging[kPathBytes];
  int parents = 0;
  char parent[kMaxParents][kPathBytes];  // innermost first
};
Slot g_slots[kSlots];
std::once_flag g_handlers_once;

/// Removes the tree `name` under `dirfd` with system calls only (async-signal-safe).
void removeTree(int dirfd, const char* name, int depth) {
  const int fd = ::openat(dirfd, name, O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
  if (fd < 0) {
    ::unlinkat(dirfd, name, 0);
    return;
  }
  alignas(8) char buf[4096];
  for (int pass = 0; pass < 1000; ++pass) {  // entries removed while listing: list again until empty
    bool any = false;
    ::lseek(fd, 0, SEEK_SET);
    for (;;) {
      const ssize_t n = ::getdents64(fd, buf, sizeof buf);
      if (n <= 0) break;
      for (ssize_t off = 0; off < n;) {
        const auto* d = reinterpret_cast<const struct dirent64*>(buf + off);
        off += d->d_reclen;
        if (std::strcmp(d->d_name, ".") == 0 || std::strcmp(d->d_name, "..") == 0) continue;
        any = true;
        if (::unlinkat(fd, d->d_name, 0) != 0 && depth < 16) removeTree(fd, d->d_name, depth + 1);
      }
    }
    if (!any) break;
  }
  ::close(fd);
  ::unlinkat(dirfd, name, AT_REMOVEDIR);
}

extern "C" void onTerminatingSignal(int sig) {
  for (Slot& s : g_slots) {
    if (!s.ready.load()) continue;
    removeTree(AT_FDCWD, s.staging, 0);
    for (int i = 0; i < s.parents; ++i) ::rmdir(s.parent[i]);
  }
  ::signal(sig, SIG_DFL);
  ::raise(sig);
}

void installHandlers() {
  for (int sig : {SIGINT, SIGTERM, SIGHUP}) {
    struct sigaction old {};
    ::sigaction(sig, nullptr, &old);
    if (old.sa_handler == SIG_IGN) continue;  // e.g. nohup: keep ignoring
    struct sigaction sa {};
    sa.sa_handler = onTerminatingSignal;
    sigemptyset(&sa.sa_mask);
    ::sigaction(sig, &sa, nullptr);
  }
}

int claimSlot(const fs::path& staging, const std::vector<fs::path>& parents) {
  std::call_once(g_handlers_once, installHandlers);
  if (staging.native().size() >= kPathBytes) return -1;
  for (int i = 0; i < kSlots; ++i) {
    bool expected = false;
    Slot& s = g_slots[i];
    if (!s.used.compare_exchange_strong(expected, true)) continue;
    // The handler reads a slot only once `ready` is set, after its paths are complete: a signal
    // in between leaves this staging directory behind, but never removes a half-copied path
    // (a prefix such as "/tmp" would be someone else's directory).
    s.parents = 0;
    for (auto it = parents.rbegin(); it != parents.rend() && s.parents < kMaxParents; ++it)
      if (it->native().size() < kPathBytes) std::strcpy(s.parent[s.parents++], it->c_str());
    std::strcpy(s.staging, staging.c_str());
    s.ready.store(true);
    return i;
  }
  return -1;  // more than kSlots at once: no cleanup on a signal, still all-or-nothing otherwise
}

void releaseSlot(int i) {
  if (i < 0) return;
  g_slots[i].ready.store(false);
  g_slots[i].used.store(false);
}

}  // namespace

// ---- AtomicFileSet ---------------------------------------------------------------------------

AtomicFileSet::~AtomicFileSet() {
  if (!done_) abort();
}

fs::path AtomicFileSet::temp(const fs::path& final_path) {
  auto [t, fd] = createTemp(final_path);
  ::close(fd);
  files_.emplace_back(t, final_path);
  return t;
}

fs::path AtomicFileSet::write(const fs::path& final_path, const std::string& text) {
  auto [t, fd] = createTemp(final_path);
  files_.emplace_back(t, final_path);
  std::size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::write(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int err = errno;
      ::close(fd);
      throw std::runtime_error(fmt::format("cannot write {}: {}", final_path.string(), std::strerror(err)));
    }
    done += static_cast<std::size_t>(n);
  }
  if (::close(fd) != 0) throw std::runtime_error(fmt::format("cannot write {}: {}", final_path.string(), std::strerror(errno)));
  return t;
}

void AtomicFileSet::commit() {
  for (const auto& [t, final_path] : files_) {
    std::error_code ec;
    fs::rename(t, final_path, ec);
    if (ec) throw std::runtime_error("cannot move " + t.string() + " to " + final_path.string() + ": " + ec.message());
  }
  done_ = true;
}

std::vector<fs::path> AtomicFileSet::finals() const {
  std::vector<fs::path> out;
  for (const auto& f : files_) out.push_back(f.second);
  return out;
}

void AtomicFileSet::drop(const fs::path& temp) {
  for (auto it = files_.begin(); it != files_.end(); ++it)
    if (it->first == temp) {
      std::error_code ec;
      fs::remove(temp, ec);
      files_.erase(it);
      return;
    }
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

// ---- OutputDir -------------------------------------------------------------------------------

namespace {

/// An output of an rsfm from before the marker: one of its files says so in its first 64 kB
/// (summary.json, tracks.csv, patches.csv, evaluation.json, scoreboard.json; a rendering's
/// truth/summary.json).
bool writtenByEarlierRsfm(const fs::path& p) {
  const std::string name = p.filename().string();
  std::error_code ec;
  if (name == "truth" && fs::is_directory(p, ec)) return writtenByEarlierRsfm(p / "summary.json");
  const char* sign = name == "summary.json"      ? "\"format\": \"rsfm-summary\""
                     : name == "tracks.csv"      ? "# rsfm-tracks "
                     : name == "patches.csv"     ? "# rsfm-patches "
                     : name == "evaluation.json" ? "\"format\": \"rsfm-evaluation\""
                     : name == "scoreboard.json" ? "\"format\": \"rsfm-scoreboard\""
                                                 : nullptr;
  if (!sign) return false;
  if (!fs::is_regular_file(p, ec)) return false;
  try {
    // The first 64 kB: keys may be sorted, "format" is not always first.
    return readAtMost(p, (1 << 16) - 1, "cannot be opened").find(sign) != std::string::npos;
  } catch (const InputError&) {
    return false;
  }
}

}  // namespace

OutputDir::~OutputDir() {
  if (!committed_) discard();
}

void OutputDir::discard() {
  std::error_code ec;
  if (!staging_.empty()) fs::remove_all(staging_, ec);
  for (auto it = created_parents_.rbegin(); it != created_parents_.rend(); ++it) fs::remove(*it, ec);  // only if empty
  releaseSlot(slot_);
  slot_ = -1;
  staging_.clear();
  created_parents_.clear();
}

std::string OutputDir::open(const fs::path& target, const std::vector<fs::path>& inputs) {
  std::error_code ec;
  const fs::path t = fs::weakly_canonical(fs::absolute(target, ec), ec);
  for (const fs::path& in : inputs) {
    if (in.empty()) continue;
    const fs::path i = fs::weakly_canonical(fs::absolute(in, ec), ec);
    // `i` inside `t` (or `t` itself).
    std::string ts = t.string(), is = i.string();
    while (ts.size() > 1 && ts.back() == '/') ts.pop_back();
    const bool inside = is == ts || (is.size() > ts.size() && is.compare(0, ts.size(), ts) == 0 && is[ts.size()] == '/');
    if (inside)
      return fmt::format("output directory {} holds the input {}: rsfm replaces its output directory whole; give another --out",
                         target.string(), in.string());
  }
  return open(target);
}

std::string OutputDir::open(const fs::path& target) {
  std::error_code ec;
  if (target.empty()) return "no output directory given";
  fs::path t = fs::absolute(target, ec).lexically_normal();
  if (ec) return fmt::format("output directory {}: {}", target.string(), ec.message());
  if (!t.has_filename()) t = t.parent_path();
  if (fs::is_symlink(t, ec)) {
    const fs::path real = fs::canonical(t, ec);
    if (!ec) t = real;
  }
  if (!t.has_parent_path() || t == t.root_path()) return fmt::format("output directory {}: not the root directory", target.string());
  if (fs::exists(t, ec)) {
    if (!fs::is_directory(t, ec)) return fmt::format("output path {} exists and is not a directory", target.string());
    bool empty = true, marked = false;
    for (fs::directory_iterator it(t, ec), end; !ec && it != end; it.increment(ec)) {
      empty = false;
      if (it->path().filename() == kMarker || writtenByEarlierRsfm(it->path())) marked = true;
    }
    if (ec) return fmt::format("output directory {} cannot be read: {}", target.string(), ec.message());
    if (!empty && !marked)
      return fmt::format("output directory {} holds files that are not an earlier rsfm output (no {} in it); rsfm replaces "
                         "its output directory whole: give a new or empty directory",
                         target.string(), kMarker);
  }
  // Missing parents are created, and removed again if the command fails.
  const fs::path parent = t.parent_path();
  std::vector<fs::path> missing;
  for (fs::path p = parent; !p.empty() && !fs::exists(p, ec); p = p.parent_path()) {
    missing.push_back(p);
    if (p == p.root_path()) break;
  }
  for (auto it = missing.rbegin(); it != missing.rend(); ++it) {
    if (!fs::create_directory(*it, ec) || ec) {
      const std::string why = ec ? ec.message() : "exists";
      for (auto jt = created_parents_.rbegin(); jt != created_parents_.rend(); ++jt) fs::remove(*jt, ec);
      created_parents_.clear();
      return fmt::format("cannot create output directory {}: {}", target.string(), why);
    }
    created_parents_.push_back(*it);
  }
  if (!fs::is_directory(parent, ec)) return fmt::format("output directory {}: {} is not a directory", target.string(), parent.string());
  std::string tmpl = (parent / hiddenName(t, ".rsfm-XXXXXX")).string();
  if (::mkdtemp(tmpl.data()) == nullptr) {
    const std::string why = std::strerror(errno);
    discard();
    return fmt::format("cannot write in {} (for output directory {}): {}", parent.string(), target.string(), why);
  }
  target_ = t;
  staging_ = tmpl;
  slot_ = claimSlot(staging_, created_parents_);
  return "";
}

void OutputDir::commit() {
  if (staging_.empty()) throw std::logic_error("OutputDir::commit without a successful open");
  {
    AtomicFileSet marker;
    marker.write(staging_ / kMarker,
                 "This directory is an rsfm output: the next rsfm run into it replaces it whole (docs/outputs.md).\n");
    marker.commit();
  }
  const mode_t mask = ::umask(0);
  ::umask(mask);
  ::chmod(staging_.c_str(), 0777 & ~mask);  // mkdtemp made it 0700
  std::error_code ec;
  if (!fs::exists(target_, ec)) {
    if (::rename(staging_.c_str(), target_.c_str()) != 0)
      throw std::runtime_error(fmt::format("cannot move the new output into {}: {}", target_.string(), std::strerror(errno)));
  } else if (::renameat2(AT_FDCWD, staging_.c_str(), AT_FDCWD, target_.c_str(), RENAME_EXCHANGE) != 0) {
    if (errno != EINVAL && errno != ENOSYS)
      throw std::runtime_error(fmt::format("cannot replace {} by the new output: {}", target_.string(), std::strerror(errno)));
    // A file system without RENAME_EXCHANGE: two renames (the target is missing in between).
    std::string old = (target_.parent_path() / hiddenName(target_, ".rsfm-old-XXXXXX")).string();
    if (::mkdtemp(old.data()) == nullptr || ::rename(target_.c_str(), old.c_str()) != 0)
      throw std::runtime_error(fmt::format("cannot replace {} by the new output: {}", target_.string(), std::strerror(errno)));
    if (::rename(staging_.c_str(), target_.c_str()) != 0) {
      const int err = errno;
      ::rename(old.c_str(), target_.c_str());
      throw std::runtime_error(fmt::format("cannot replace {} by the new output: {}", target_.string(), std::strerror(err)));
    }
    staging_ = old;
  }
  // The staging path now holds the old contents (or nothing).
  committed_ = true;
  fs::remove_all(staging_, ec);
  releaseSlot(slot_);
  slot_ = -1;
}

}  // namespace rsfm::io
