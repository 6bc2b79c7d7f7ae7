#pragma once
// All-or-nothing outputs (issue 17; docs/outputs.md, "Output directories").
//
// OutputDir: a command's output directory. Everything is written into a fresh staging directory
// beside the target (mkdtemp: an unpredictable name, mode 0700, so nothing in it can be planted
// or followed), and commit() puts it in the target's place in one rename (renameat2 with
// RENAME_EXCHANGE when the target exists, whose old contents are then removed). Without commit
// (an error, an exception, SIGINT, SIGTERM or SIGHUP) the staging directory and every parent
// directory the command created are removed: the target stays exactly as it was. An existing
// target is replaced only when it is empty or an earlier rsfm output (it holds the marker file
// `.rsfm-output`, or, from before the marker, an rsfm summary.json, tracks.csv or patches.csv);
// anything else is refused, so `--out ~` cannot delete a home directory.
//
// AtomicFileSet: files written under temporary names in their final directory and renamed into
// place by commit(); the temporaries are created exclusively (O_EXCL | O_NOFOLLOW, random
// names), so a planted symlink is never followed. Used inside an OutputDir's staging directory
// and, for `rsfm evaluate`, to add files to an existing estimate directory.
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
  /// A new, empty temporary file for `final_path`, created exclusively in the same directory with
  /// the same extension (tools that infer the format from it still work); throws
  /// std::runtime_error when it cannot be created.
  std::filesystem::path temp(const std::filesystem::path& final_path);
  /// Writes `text` to a temporary of `final_path` and returns the temporary's path; throws
  /// std::runtime_error on failure.
  std::filesystem::path write(const std::filesystem::path& final_path, const std::string& text);
  /// Removes one temporary (as returned by temp() or write()) from the set: commit() leaves no
  /// file for it (a figure whose script failed, docs/outputs.md "Figures").
  void drop(const std::filesystem::path& temp);
  /// The final paths of the files in the set, in the order they were added.
  std::vector<std::filesystem::path> finals() const;
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

class OutputDir {
 public:
  OutputDir() = default;
  OutputDir(const OutputDir&) = delete;
  OutputDir& operator=(const OutputDir&) = delete;
  ~OutputDir();
  /// Prepares `target` (creating its missing parents) and the staging directory. Returns "" or a
  /// one-line reason: the target is not a directory, holds files that are not an rsfm output,
  /// or its parent cannot be created or written.
  std::string open(const std::filesystem::path& target);
  /// The same, also refusing a target that holds one of `inputs` (files or directories the
  /// command reads): replacing the target would delete its own input.
  std::string open(const std::filesystem::path& target, const std::vector<std::filesystem::path>& inputs);
  /// Where to write: the staging directory (valid after a successful open()).
  const std::filesystem::path& path() const { return staging_; }
  const std::filesystem::path& target() const { return target_; }
  /// Puts the staging directory in the target's place and removes the old contents; throws
  /// std::runtime_error (the target then keeps its old contents).
  void commit();

  /// The marker file every committed output directory holds.
  static constexpr const char* kMarker = ".rsfm-output";

 private:
  void discard();
  std::filesystem::path target_, staging_;
  std::vector<std::filesystem::path> created_parents_;  // innermost last
  int slot_ = -1;                                        // in the signal handler's list
  bool committed_ = false;
};

}  // namespace rsfm::io
