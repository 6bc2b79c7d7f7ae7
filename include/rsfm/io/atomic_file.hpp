#pragma once
// Writing a set of output files all-or-nothing: each file is written under a temporary name in
// its final directory and renamed into place only by commit(); if commit() is never reached
// (error, exception) the temporaries are removed, so no half-written file replaces a good one.
#include <filesystem>
#include <string>
#include <vector>

namespace rsfm::io {

class AtomicFileSet {
 public:
  AtomicFileSet() = default;
  AtomicFileSet(const AtomicFileSet&) = delete;
  AtomicFileSet& operator=(const AtomicFileSet&) = delete;
  ~AtomicFileSet();
  /// Temporary path for `final_path`; same directory and extension (so tools that infer the
  /// format from the extension still work).
  std::filesystem::path temp(const std::filesystem::path& final_path);
  /// Writes `text` to the temporary of `final_path` and returns the temporary's path; throws
  /// std::runtime_error on failure.
  std::filesystem::path write(const std::filesystem::path& final_path, const std::string& text);
  /// Renames every temporary into place.
  void commit();
  /// Removes every temporary.
  void abort();

 private:
  std::vector<std::pair<std::filesystem::path, std::filesystem::path>> files_;  // temp, final
  bool done_ = false;
};

/// Writes each (path, text) all-or-nothing (an AtomicFileSet committed at the end).
void writeAllOrNothing(const std::vector<std::pair<std::filesystem::path, std::string>>& files);

/// Creates `dir` if needed and checks that a file can be created in it. Returns an empty string
/// on success, else a one-line reason.
std::string ensureWritableDirectory(const std::filesystem::path& dir);

}  // namespace rsfm::io
