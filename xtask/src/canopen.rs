//! CANopen on the host test bus (issue 22): a third-party master (the
//! Python `canopen` package over `python-can`) against several drives, each
//! the real drive code with its own simulated motor, on `foc-canbus`'s
//! virtual bus; the EDS is the checked-in one the drive's object
//! dictionary generates (checked by `cargo test -p foc-canopen --test eds`).
//!
//! The Python packages are pinned and installed into the project's virtual
//! environment (target/python-venv) from PyPI when missing.

use std::process::Command;

use crate::util::{cargo, root, run, target_dir, Error, Result};

/// The master's packages, pinned (the versions the tests were written
/// against).
pub const PACKAGES: [&str; 3] = ["python-can==4.6.1", "canopen==2.4.1", "pyserial==3.5"];

/// Build the bus, install the master's packages, run the master's tests.
pub fn run_tests() -> Result {
    run(cargo(["build", "-p", "foc-canbus"]))?;
    let bus = target_dir().join("debug").join("foc-canbus");
    if !bus.exists() {
        return Err(Error(format!("{} was not built", bus.display())));
    }
    let python = crate::python::venv()?;
    let mut pip = crate::python::pip(&python);
    pip.args(PACKAGES);
    run(pip)?;
    let mut t = Command::new(&python);
    t.current_dir(root())
        .env("FOC_CANBUS", &bus)
        .env("FOC_EDS", root().join("docs/canopen/foc-drive.eds"))
        .env("PYTHONPATH", root().join("canbus/master"))
        .args(["-m", "unittest", "discover", "-s", "canbus/master", "-v"]);
    run(t)
}
