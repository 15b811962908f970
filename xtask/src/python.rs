//! The Python package's tests (`python/`, `foc-drive`): installed into a
//! virtual environment under the target directory (with the system's site
//! packages, so an installed numpy is used; pip fetches what is missing),
//! then its unittest suite against `foc-ctl simulate` (the debug binary).

use std::path::{Path, PathBuf};
use std::process::Command;

use crate::util::{cargo, root, run, target_dir, Error, Result};

/// Build `foc-ctl`, install the package, run its tests.
pub fn run_tests() -> Result {
    run(cargo(["build", "-p", "foc-ctl"]))?;
    let python = venv()?;
    let mut pip = pip(&python);
    // Build with the environment's setuptools and wheel when it has them
    // (no download); else pip fetches them (build isolation).
    if has_build_backend(&python) {
        pip.arg("--no-build-isolation");
    }
    pip.arg(root().join("python"));
    run(pip)?;
    let ctl = target_dir().join("debug").join("foc-ctl");
    if !ctl.exists() {
        return Err(Error(format!("{} was not built", ctl.display())));
    }
    let mut t = Command::new(&python);
    t.current_dir(root()).env("FOC_CTL", &ctl).args([
        "-m",
        "unittest",
        "discover",
        "-s",
        "python/tests",
        "-v",
    ]);
    run(t)
}

/// The project's virtual environment (target/python-venv, with the
/// system's site packages), created if missing: its `python3`.
pub fn venv() -> Result<PathBuf> {
    let venv = target_dir().join("python-venv");
    let python = venv.join("bin").join("python3");
    if !python.exists() {
        let mut c = Command::new("python3");
        c.args(["-m", "venv", "--system-site-packages"]).arg(&venv);
        run(c)?;
    }
    Ok(python)
}

/// `python -m pip install --quiet` in the environment of `python`.
pub fn pip(python: &Path) -> Command {
    let mut pip = Command::new(python);
    pip.args([
        "-m",
        "pip",
        "install",
        "--quiet",
        "--disable-pip-version-check",
    ]);
    pip
}

fn has_build_backend(python: &Path) -> bool {
    Command::new(python)
        .args(["-c", "import setuptools, wheel"])
        .status()
        .is_ok_and(|s| s.success())
}
