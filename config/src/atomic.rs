//! Output files that are never destructive.
//!
//! Every file taut writes for a person (parameters, JSON reports, recordings, figures) goes
//! through here:
//!
//! 1. [`check_output`] before any work is done: the path must be a regular file or not exist yet
//!    (a device node, symlink, directory or fifo is refused, never replaced), its directory must
//!    exist, and it must not be one of the command's input files (same device and inode, so
//!    `rec.csv`, `./rec.csv` and a hard link are all caught).
//! 2. [`write_atomic`]: a new temporary file in the target directory (`O_EXCL`, never an existing
//!    name), written, fsynced, renamed over the target, then the directory fsynced so the rename
//!    itself survives a power cut. A reader sees the old file or the new one; a writer that fails
//!    or is killed midway leaves the old file untouched (and removes its temporary file when it
//!    can).
//! 3. [`Staging`] for a set of files that belong together (the figures of one run): each file is
//!    written into a hidden staging directory inside the target directory and only when all of
//!    them are complete are they renamed into place, one `rename(2)` each, and the directory
//!    fsynced. A failed render leaves the old figures as they were. The set is not one atomic
//!    step (POSIX has no multi-file rename; swapping the whole directory would throw away the
//!    user's other files in it), but the window is a handful of renames, not a render.

use std::fmt;
use std::io::Write;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};

/// Why an output path is refused.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum OutputError {
    /// Something that is not a regular file is at the path.
    NotRegular {
        /// The output path.
        path: PathBuf,
        /// What is there: `directory`, `symlink`, `device node`, `fifo`, `socket`.
        what: &'static str,
    },
    /// The output path is one of the command's inputs.
    IsInput {
        /// The output path.
        path: PathBuf,
        /// The input it would overwrite.
        input: PathBuf,
    },
    /// The directory of the output does not exist or is not a directory.
    NoDirectory {
        /// The output path.
        path: PathBuf,
    },
    /// The path cannot be looked at (too long, a file where a directory should be, ...).
    Unusable {
        /// The output path.
        path: PathBuf,
        /// What the system said.
        reason: String,
    },
    /// Not a file path (empty, `..`, `/`).
    NotAFilePath {
        /// The output path.
        path: PathBuf,
    },
}

impl fmt::Display for OutputError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            OutputError::NotRegular { path, what } => write!(
                f,
                "{}: is a {what}, not a regular file; refusing to replace it (give the path of a new or regular file)",
                path.display()
            ),
            OutputError::IsInput { path, input } => write!(
                f,
                "{}: is the input file {}; refusing to write over it (choose another output path)",
                path.display(),
                input.display()
            ),
            OutputError::NoDirectory { path } => {
                write!(f, "{}: its directory does not exist; create it first", path.display())
            }
            OutputError::NotAFilePath { path } => write!(f, "`{}` is not a file path", path.display()),
            OutputError::Unusable { path, reason } => write!(f, "{}: cannot write there: {reason}", path.display()),
        }
    }
}

impl std::error::Error for OutputError {}

impl From<OutputError> for std::io::Error {
    fn from(e: OutputError) -> Self {
        std::io::Error::other(e)
    }
}

fn kind_of(ft: std::fs::FileType) -> Option<&'static str> {
    use std::os::unix::fs::FileTypeExt;
    if ft.is_file() {
        None
    } else if ft.is_dir() {
        Some("directory")
    } else if ft.is_symlink() {
        Some("symlink")
    } else if ft.is_block_device() || ft.is_char_device() {
        Some("device node")
    } else if ft.is_fifo() {
        Some("fifo")
    } else if ft.is_socket() {
        Some("socket")
    } else {
        Some("special file")
    }
}

/// The directory a file path lives in (`.` for a bare name).
fn dir_of(path: &Path) -> Result<PathBuf, OutputError> {
    if path.file_name().is_none() {
        return Err(OutputError::NotAFilePath { path: path.to_path_buf() });
    }
    Ok(match path.parent() {
        Some(d) if !d.as_os_str().is_empty() => d.to_path_buf(),
        _ => PathBuf::from("."),
    })
}

/// Checks that `path` may be written by [`write_atomic`] without destroying anything: it is a
/// regular file or absent, its directory exists, and it is none of `inputs`.
pub fn check_output(path: &Path, inputs: &[&Path]) -> Result<(), OutputError> {
    let dir = dir_of(path)?;
    if !std::fs::metadata(&dir).is_ok_and(|m| m.is_dir()) {
        return Err(OutputError::NoDirectory { path: path.to_path_buf() });
    }
    let meta = match std::fs::symlink_metadata(path) {
        Ok(m) => m,
        Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(()),
        Err(e) => return Err(OutputError::Unusable { path: path.to_path_buf(), reason: e.to_string() }),
    };
    if let Some(what) = kind_of(meta.file_type()) {
        return Err(OutputError::NotRegular { path: path.to_path_buf(), what });
    }
    use std::os::unix::fs::MetadataExt;
    for input in inputs {
        // `metadata` follows symlinks: an input given through a link is still the same file.
        if let Ok(m) = std::fs::metadata(input) {
            if m.dev() == meta.dev() && m.ino() == meta.ino() {
                return Err(OutputError::IsInput { path: path.to_path_buf(), input: input.to_path_buf() });
            }
        }
    }
    Ok(())
}

/// A temporary name no other writer uses: process id, a per-process counter and the clock.
fn temp_name(dir: &Path, name: &std::ffi::OsStr) -> PathBuf {
    static COUNTER: AtomicU64 = AtomicU64::new(0);
    // Relaxed: only uniqueness matters, not ordering with other memory.
    let k = COUNTER.fetch_add(1, Ordering::Relaxed);
    let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
    let mut stem = name.to_string_lossy().into_owned();
    // Keep the temporary name within NAME_MAX however long the target's name is.
    if stem.len() > 160 {
        let mut cut = 160;
        while !stem.is_char_boundary(cut) {
            cut -= 1;
        }
        stem.truncate(cut);
    }
    dir.join(format!(".{stem}.tmp{}-{k}-{nanos}", std::process::id()))
}

/// fsyncs a directory so that a rename in it is durable.
pub fn sync_dir(dir: &Path) -> std::io::Result<()> {
    std::fs::File::open(dir)?.sync_all()
}

/// Writes `path` atomically with what `fill` writes into the temporary file; see the module doc.
/// On any error the target is untouched and the temporary file removed.
pub fn write_atomic_with(path: &Path, fill: impl FnOnce(&mut std::fs::File) -> std::io::Result<()>) -> std::io::Result<()> {
    check_output(path, &[])?;
    let dir = dir_of(path)?;
    let name = path.file_name().ok_or_else(|| OutputError::NotAFilePath { path: path.to_path_buf() })?;
    let tmp = temp_name(&dir, name);
    let result = (|| {
        let mut f = std::fs::OpenOptions::new().write(true).create_new(true).open(&tmp)?;
        // Keep the permissions of the file being replaced (a params file may be group-readable on
        // purpose); a new file gets the default mode.
        if let Ok(m) = std::fs::metadata(path) {
            let _ = f.set_permissions(m.permissions());
        }
        fill(&mut f)?;
        f.flush()?;
        f.sync_all()?;
        drop(f);
        // Checked again just before the rename: something may have appeared at the path meanwhile.
        check_output(path, &[])?;
        std::fs::rename(&tmp, path)
    })();
    if result.is_err() {
        let _ = std::fs::remove_file(&tmp);
        return result;
    }
    sync_dir(&dir)
}

/// Writes `bytes` to `path` atomically; see the module doc.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    write_atomic_with(path, |f| f.write_all(bytes))
}

/// A set of files that go into one directory together (all or nothing); see the module doc.
#[derive(Debug)]
pub struct Staging {
    target: PathBuf,
    stage: PathBuf,
    files: Vec<std::ffi::OsString>,
    inputs: Vec<PathBuf>,
    /// The target directory was made for this set: removed again (if empty) when the set fails.
    created: bool,
    committed: bool,
}

impl Staging {
    /// Starts a set for directory `target` (created if missing, parents too); `inputs` are the
    /// command's input files, which no file of the set may replace.
    pub fn new(target: &Path, inputs: &[&Path]) -> std::io::Result<Self> {
        let mut created = false;
        match std::fs::metadata(target) {
            Ok(m) if !m.is_dir() => {
                return Err(std::io::Error::other(format!(
                    "{}: exists and is not a directory; give a directory for the figures",
                    target.display()
                )))
            }
            Ok(_) => {}
            Err(_) => {
                std::fs::create_dir_all(target)
                    .map_err(|e| std::io::Error::new(e.kind(), format!("creating {}: {e}", target.display())))?;
                created = true;
            }
        }
        let stage = temp_name(target, std::ffi::OsStr::new("taut-staging"));
        std::fs::create_dir(&stage).map_err(|e| std::io::Error::new(e.kind(), format!("creating {}: {e}", stage.display())))?;
        Ok(Staging {
            target: target.to_path_buf(),
            stage,
            files: Vec::new(),
            inputs: inputs.iter().map(|p| p.to_path_buf()).collect(),
            created,
            committed: false,
        })
    }

    /// The directory the set goes into.
    pub fn target(&self) -> &Path {
        &self.target
    }

    /// Where to write the file `name` of the set (inside the staging directory). Refuses a name
    /// whose final place holds something that must not be replaced.
    pub fn path(&mut self, name: &str) -> std::io::Result<PathBuf> {
        let inputs: Vec<&Path> = self.inputs.iter().map(PathBuf::as_path).collect();
        check_output(&self.target.join(name), &inputs)?;
        self.files.push(name.into());
        Ok(self.stage.join(name))
    }

    /// Moves every file of the set into place (fsync each, rename each, fsync the directory) and
    /// removes the staging directory.
    pub fn commit(mut self) -> std::io::Result<()> {
        let inputs: Vec<&Path> = self.inputs.iter().map(PathBuf::as_path).collect();
        for f in &self.files {
            std::fs::File::open(self.stage.join(f))?.sync_all()?;
            check_output(&self.target.join(f), &inputs)?;
        }
        self.committed = true;
        for f in std::mem::take(&mut self.files) {
            std::fs::rename(self.stage.join(&f), self.target.join(&f))?;
        }
        sync_dir(&self.target)
        // Drop removes the (now empty) staging directory.
    }
}

impl Drop for Staging {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.stage);
        if self.created && !self.committed {
            // Only an empty directory goes: anything else in it is not ours.
            let _ = std::fs::remove_dir(&self.target);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tmpdir(tag: &str) -> PathBuf {
        let d = std::env::temp_dir().join(format!("taut-atomic-{tag}-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&d);
        std::fs::create_dir_all(&d).unwrap();
        d
    }

    fn leftovers(d: &Path) -> Vec<String> {
        std::fs::read_dir(d)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .filter(|n| n.starts_with('.'))
            .collect()
    }

    #[test]
    fn failure_midway_keeps_the_old_file_and_no_temporary() {
        let d = tmpdir("midway");
        let p = d.join("params.toml");
        std::fs::write(&p, "old").unwrap();
        let e = write_atomic_with(&p, |f| {
            f.write_all(b"half of the new con")?;
            Err(std::io::Error::other("disk full"))
        })
        .unwrap_err();
        assert!(e.to_string().contains("disk full"));
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "old");
        assert!(leftovers(&d).is_empty(), "{:?}", leftovers(&d));
        write_atomic(&p, b"new").unwrap();
        assert_eq!(std::fs::read_to_string(&p).unwrap(), "new");
        assert!(leftovers(&d).is_empty());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn refuses_what_is_not_a_regular_file() {
        let d = tmpdir("kinds");
        let target = d.join("real");
        std::fs::write(&target, "keep").unwrap();
        let link = d.join("link");
        std::os::unix::fs::symlink(&target, &link).unwrap();
        let e = write_atomic(&link, b"x").unwrap_err();
        assert!(e.to_string().contains("symlink"), "{e}");
        assert!(std::fs::symlink_metadata(&link).unwrap().file_type().is_symlink());
        let e = write_atomic(&d, b"x").unwrap_err();
        assert!(e.to_string().contains("directory"), "{e}");
        let e = write_atomic(Path::new("/dev/null"), b"x").unwrap_err();
        assert!(e.to_string().contains("device node"), "{e}");
        let e = write_atomic(&d.join("no/such/dir/f"), b"x").unwrap_err();
        assert!(e.to_string().contains("does not exist"), "{e}");
        assert_eq!(std::fs::read_to_string(&target).unwrap(), "keep");
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn input_is_recognised_by_inode() {
        let d = tmpdir("input");
        let rec = d.join("rec.csv");
        std::fs::write(&rec, "data").unwrap();
        let hard = d.join("hard.csv");
        std::fs::hard_link(&rec, &hard).unwrap();
        let dotted = d.join(".").join("rec.csv");
        for out in [&rec, &hard, &dotted] {
            assert!(matches!(check_output(out, &[&rec]), Err(OutputError::IsInput { .. })), "{}", out.display());
        }
        assert!(check_output(&d.join("other.csv"), &[&rec]).is_ok());
        std::fs::remove_dir_all(&d).unwrap();
    }

    #[test]
    fn staging_is_all_or_nothing() {
        let d = tmpdir("stage");
        std::fs::write(d.join("a.svg"), "old a").unwrap();
        std::fs::write(d.join("b.svg"), "old b").unwrap();
        {
            let mut s = Staging::new(&d, &[]).unwrap();
            std::fs::write(s.path("a.svg").unwrap(), "new a").unwrap();
            // The render of b fails: the set is dropped without commit.
        }
        assert_eq!(std::fs::read_to_string(d.join("a.svg")).unwrap(), "old a");
        assert!(leftovers(&d).is_empty(), "{:?}", leftovers(&d));
        let mut s = Staging::new(&d, &[]).unwrap();
        std::fs::write(s.path("a.svg").unwrap(), "new a").unwrap();
        std::fs::write(s.path("b.svg").unwrap(), "new b").unwrap();
        s.commit().unwrap();
        assert_eq!(std::fs::read_to_string(d.join("a.svg")).unwrap(), "new a");
        assert_eq!(std::fs::read_to_string(d.join("b.svg")).unwrap(), "new b");
        assert!(leftovers(&d).is_empty(), "{:?}", leftovers(&d));
        // A directory made for a set that fails is removed again.
        let fresh = d.join("new/figs");
        {
            let mut s = Staging::new(&fresh, &[]).unwrap();
            std::fs::write(s.path("a.svg").unwrap(), "x").unwrap();
        }
        assert!(!fresh.exists());
        std::fs::remove_dir_all(&d).unwrap();
    }
}
