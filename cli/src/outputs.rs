//! Output paths checked before any work is done: a calibration that runs for a minute and then
//! cannot write its result, or writes it over its own input, wastes the minute or the input.
//! The writing itself is `taut_config::atomic`.

use anyhow::{bail, Result};
use std::path::{Path, PathBuf};
use taut_config::atomic::{check_output, Staging};

/// One output of a command: the flag that named it and the path.
pub type Output<'a> = (&'static str, &'a Path);

/// Checks every file output against the inputs and against each other, and every figure
/// directory for being a directory or absent.
pub fn check(files: &[Output], figure_dirs: &[Output], inputs: &[&Path]) -> Result<()> {
    for (flag, p) in files {
        check_output(p, inputs).map_err(|e| anyhow::anyhow!("{flag}: {e}"))?;
    }
    for (k, (fa, a)) in files.iter().enumerate() {
        for (fb, b) in &files[k + 1..] {
            if same_place(a, b) {
                bail!("{fa} and {fb} name the same file {}; give each output its own path", a.display());
            }
        }
    }
    for (flag, d) in figure_dirs {
        if let Ok(m) = std::fs::symlink_metadata(d) {
            if !std::fs::metadata(d).is_ok_and(|m| m.is_dir()) {
                let what = if m.file_type().is_symlink() { "a symlink to something that is not a directory" } else { "not a directory" };
                bail!("{flag}: {} is {what}; give a directory for the figures", d.display());
            }
        }
    }
    Ok(())
}

/// The outputs of an analysis command (`calibrate`, `diagnose`): the files `--json`, `--out` and
/// `--report` and the figure directory `--plot`, checked against the recording and the config
/// (see [`check`]). Returns the inputs for the command's later use.
pub fn check_analysis<'a>(
    recording: &'a Path,
    config: Option<&'a Path>,
    json: Option<&Path>,
    out: Option<&Path>,
    report: Option<&Path>,
    plot: Option<&Path>,
) -> Result<Vec<&'a Path>> {
    let inputs: Vec<&Path> = std::iter::once(recording).chain(config).collect();
    let files: Vec<Output> =
        json.map(|p| ("--json", p)).into_iter().chain(out.map(|p| ("--out", p))).chain(report.map(|p| ("--report", p))).collect();
    let dirs: Vec<Output> = plot.map(|p| ("--plot", p)).into_iter().collect();
    check(&files, &dirs, &inputs)?;
    Ok(inputs)
}

/// Two output paths that would be the same file: the same inode if both exist, else the same
/// absolute path.
fn same_place(a: &Path, b: &Path) -> bool {
    use std::os::unix::fs::MetadataExt;
    match (std::fs::metadata(a), std::fs::metadata(b)) {
        (Ok(x), Ok(y)) => x.dev() == y.dev() && x.ino() == y.ino(),
        _ => absolute(a) == absolute(b),
    }
}

fn absolute(p: &Path) -> PathBuf {
    let p = std::path::absolute(p).unwrap_or_else(|_| p.to_path_buf());
    // `a/./b` and `a/b` are one place; `..` is left alone (it may cross a symlink).
    p.components().filter(|c| !matches!(c, std::path::Component::CurDir)).collect()
}

/// Starts a figure set in `dir` (see `taut_config::atomic::Staging`).
pub fn figures(dir: &Path, inputs: &[&Path]) -> Result<Staging> {
    Ok(Staging::new(dir, inputs)?)
}
