//! The files generated from the command line's definition: the manual pages (clap_mangen) and
//! the shell completions (clap_complete). Copies are checked in under `cli/generated/` for
//! packagers (`deploy/README.md`); a test fails when they are stale. Regenerate with
//! `TAUT_UPDATE_GENERATED=1 cargo test -p taut-cli generated`.

use anyhow::Result;
use clap_complete::Shell;

/// The shells whose completions are checked in.
#[cfg(test)]
pub const SHELLS: [Shell; 3] = [Shell::Bash, Shell::Zsh, Shell::Fish];

/// `taut.1` and one page per subcommand (`taut-ctl.1`, ...), with their bytes.
pub fn man_pages() -> Result<Vec<(String, Vec<u8>)>> {
    let cmd = crate::command();
    let mut out = Vec::new();
    let mut buf = Vec::new();
    clap_mangen::Man::new(cmd.clone()).render(&mut buf)?;
    out.push(("taut.1".to_string(), buf));
    for sub in cmd.get_subcommands() {
        let name = format!("taut-{}", sub.get_name());
        let mut buf = Vec::new();
        // clap takes a `'static` name without its `string` feature: a few bytes per page, once.
        let title: &'static str = Box::leak(name.clone().into_boxed_str());
        clap_mangen::Man::new(sub.clone().name(title)).render(&mut buf)?;
        out.push((format!("{name}.1"), buf));
    }
    Ok(out)
}

/// The completion script of `shell`.
pub fn completions(shell: Shell) -> Vec<u8> {
    let mut buf = Vec::new();
    clap_complete::generate(shell, &mut crate::command(), "taut", &mut buf);
    buf
}

/// Every generated file under `cli/generated/`, relative paths and bytes.
#[cfg(test)]
pub fn all() -> Result<Vec<(String, Vec<u8>)>> {
    let mut files: Vec<(String, Vec<u8>)> = man_pages()?.into_iter().map(|(n, b)| (format!("man/{n}"), b)).collect();
    for sh in SHELLS {
        let name = match sh {
            Shell::Bash => "taut.bash",
            Shell::Zsh => "_taut",
            Shell::Fish => "taut.fish",
            _ => unreachable!("not in SHELLS"),
        };
        files.push((format!("completions/{name}"), completions(sh)));
    }
    Ok(files)
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    /// The checked-in copies are what the command line generates now (or, with
    /// TAUT_UPDATE_GENERATED=1, are rewritten).
    /// The checked-in files are those of the default build (with `taut demo` and `simulate`);
    /// the robot's build (`--no-default-features`) has fewer pages and is not compared.
    #[test]
    fn generated_files_are_not_stale() {
        if cfg!(not(feature = "sim")) {
            return;
        }
        let root = Path::new(env!("CARGO_MANIFEST_DIR")).join("generated");
        let update = std::env::var_os("TAUT_UPDATE_GENERATED").is_some();
        let files = super::all().unwrap();
        assert!(files.len() > 10 && files.iter().any(|(n, _)| n == "man/taut-ctl.1"));
        let mut stale = Vec::new();
        for (name, bytes) in &files {
            let p = root.join(name);
            if update {
                std::fs::create_dir_all(p.parent().unwrap()).unwrap();
                std::fs::write(&p, bytes).unwrap();
            } else if std::fs::read(&p).ok().as_deref() != Some(bytes.as_slice()) {
                stale.push(name.clone());
            }
        }
        // No file is left over from a subcommand that is gone.
        for dir in ["man", "completions"] {
            for e in std::fs::read_dir(root.join(dir)).unwrap() {
                let n = format!("{dir}/{}", e.unwrap().file_name().to_string_lossy());
                if !files.iter().any(|(f, _)| *f == n) {
                    stale.push(format!("{n} (no longer generated)"));
                }
            }
        }
        assert!(stale.is_empty(), "stale in cli/generated: {stale:?}; run TAUT_UPDATE_GENERATED=1 cargo test -p taut-cli generated");
    }

    /// Every subcommand's page names its options (what `man taut-ctl` must show).
    #[test]
    fn the_pages_carry_the_subcommands_and_their_help() {
        let pages = super::man_pages().unwrap();
        let top = String::from_utf8(pages[0].1.clone()).unwrap();
        for sub in ["calibrate", "start", "ctl", "completions", "man"] {
            assert!(top.contains(sub), "taut.1 does not name {sub}");
        }
        let ctl = pages.iter().find(|(n, _)| n == "taut-ctl.1").map(|(_, b)| String::from_utf8_lossy(b).into_owned()).unwrap();
        assert!(ctl.contains("\\-\\-socket") && ctl.contains("watch") && ctl.contains("taut\\-sim\\-data"), "{ctl}");
        let bash = String::from_utf8(super::completions(clap_complete::Shell::Bash)).unwrap();
        assert!(bash.contains("recalibrate") && bash.contains("--tolerance"));
    }
}
