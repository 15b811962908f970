//! `cargo xtask dashboard`: foc-ctl's dashboard in a real headless browser
//! (Debian's Chromium, driven over WebDriver by chromedriver): the page
//! loads, a signal is plotted live, a console command round-trips, a
//! refusal shows its reason, the setup wizard completes
//! (ctl/web/tests/dashboard_test.py, standard library only). Screenshots
//! in out/dashboard for a person to look at.

use std::path::Path;
use std::process::Command;

use crate::util::{cargo, root, run, target_dir, Error, Result};

const CHROMIUM: &str = "/usr/bin/chromium";
const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

/// Build foc-ctl, run the browser test.
pub fn run_tests() -> Result {
    for (path, pkg) in [(CHROMIUM, "chromium"), (CHROMEDRIVER, "chromium-driver")] {
        if !Path::new(path).exists() {
            return Err(Error(format!(
                "{path} is missing: install Debian's `{pkg}` (`apt-get install chromium chromium-driver`; .ci/run does)"
            )));
        }
    }
    run(cargo(["build", "-p", "foc-ctl"]))?;
    let ctl = target_dir().join("debug").join("foc-ctl");
    let out = root().join("out/dashboard");
    let mut t = Command::new("python3");
    t.current_dir(root())
        .env("FOC_CTL", &ctl)
        .env("CHROMIUM", CHROMIUM)
        .env("CHROMEDRIVER", CHROMEDRIVER)
        .env("OUT", &out)
        .arg("ctl/web/tests/dashboard_test.py");
    run(t)?;
    println!("screenshots in {}", out.display());
    Ok(())
}
