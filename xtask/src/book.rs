//! `cargo xtask book`: the book (mdBook, `docs/`) built into
//! `target/book`, with every internal link checked; and `cargo xtask doc`:
//! the library crates' API docs with rustdoc warnings denied.
//!
//! mdBook is installed into `target/tools` when it is missing (never
//! globally), at the version pinned here and without its server features.
//! The link check is ours because mdBook only reports broken links that it
//! rewrites, not anchors nor links to the repository's files; the markdown
//! is parsed with `pulldown-cmark`, the parser mdBook itself uses.

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

use pulldown_cmark::{Event, HeadingLevel, Options, Parser, Tag, TagEnd};

use crate::util::{self, Error, Result};

/// The mdBook release the book is built with.
const MDBOOK_VERSION: &str = "0.5.4";

/// The library crates whose API docs `cargo xtask doc` builds.
pub const DOC_CRATES: [&str; 11] = [
    "foc-core",
    "foc-service",
    "foc-protocol",
    "foc-store",
    "foc-canopen",
    "foc-plant",
    "foc-plot",
    "foc-bench",
    "foc-simdrive",
    "foc-canbus",
    "foc-ctl",
];

/// The markdown files outside the book whose links are checked too.
const ROOT_PAGES: [&str; 3] = ["README.md", "CONTRIBUTING.md", "CHANGELOG.md"];

/// `cargo xtask book` options.
#[derive(Debug, Default, clap::Args)]
pub struct BookArgs {
    /// Rewrite the generated tables (docs/src/tables/) from the code first.
    #[arg(long)]
    pub bless: bool,
}

/// `cargo xtask book`: the tables against the code, then install mdBook if
/// needed, build, check the links.
pub fn run_cmd(args: &BookArgs) -> Result {
    let problems = crate::doctables::check(args.bless)?;
    if !problems.is_empty() {
        for p in &problems {
            eprintln!("  {p}");
        }
        return Err(Error(format!(
            "{} tables of the book disagree with the code",
            problems.len()
        )));
    }
    let mdbook = ensure_mdbook()?;
    let mut build = util::command(&mdbook.to_string_lossy(), ["build"]);
    build.current_dir(util::root().join("docs"));
    util::run(build)?;
    let broken = check_links()?;
    if broken.is_empty() {
        println!(
            "book: {} (every internal link and anchor resolves)",
            util::target_dir().join("book/index.html").display()
        );
        Ok(())
    } else {
        for b in &broken {
            eprintln!("  broken link: {b}");
        }
        Err(Error(format!("{} broken links in the docs", broken.len())))
    }
}

/// `cargo xtask doc`: `cargo doc --no-deps` of [`DOC_CRATES`] with rustdoc
/// warnings (broken intra-doc links, missing docs...) denied.
pub fn api_docs() -> Result {
    let mut args = vec!["doc".to_string(), "--no-deps".to_string()];
    for c in DOC_CRATES {
        args.push("-p".into());
        args.push(c.into());
    }
    let mut cmd = util::cargo(&args);
    cmd.env("RUSTDOCFLAGS", "-D warnings");
    util::run(cmd)
}

/// The mdbook binary under `target/tools`, installed there if missing or of
/// another version.
fn ensure_mdbook() -> Result<PathBuf> {
    let root = util::target_dir().join("tools");
    let bin = root.join("bin/mdbook");
    let have = util::output(util::command(&bin.to_string_lossy(), ["--version"]));
    if have.is_ok_and(|v| v.trim().ends_with(MDBOOK_VERSION)) {
        return Ok(bin);
    }
    println!(
        "mdBook {MDBOOK_VERSION} is not in {}: installing it there",
        root.display()
    );
    util::run(util::cargo([
        "install",
        "mdbook",
        "--version",
        MDBOOK_VERSION,
        "--locked",
        "--no-default-features",
        "--root",
        &root.to_string_lossy(),
    ]))?;
    Ok(bin)
}

/// Every relative link in the book's sources and the root pages whose file
/// or `#anchor` does not exist, as "file: target".
pub fn check_links() -> Result<Vec<String>> {
    let root = util::root();
    let mut pages = Vec::new();
    collect_markdown(&root.join("docs/src"), &mut pages)?;
    pages.extend(ROOT_PAGES.iter().map(|p| root.join(p)));
    let mut broken = Vec::new();
    for page in &pages {
        let text = read(page)?;
        for link in links(&text) {
            if let Some(why) = check_link(page, &link)? {
                let shown = page.strip_prefix(&root).unwrap_or(page);
                broken.push(format!("{}: {link} ({why})", shown.display()));
            }
        }
    }
    Ok(broken)
}

/// Why `link` (as written in `page`) is broken, or `None`.
fn check_link(page: &Path, link: &str) -> Result<Option<&'static str>> {
    if link.contains("://") || link.starts_with("mailto:") {
        return Ok(None);
    }
    let (file, anchor) = match link.split_once('#') {
        Some((f, a)) => (f, Some(a)),
        None => (link, None),
    };
    let dir = page.parent().unwrap_or(Path::new("."));
    let target = if file.is_empty() {
        page.to_path_buf()
    } else {
        dir.join(file)
    };
    if !target.exists() {
        return Ok(Some("no such file"));
    }
    let Some(anchor) = anchor else {
        return Ok(None);
    };
    if target.extension().is_some_and(|e| e == "md") && !anchors(&read(&target)?).contains(anchor) {
        return Ok(Some("no such heading"));
    }
    Ok(None)
}

fn read(path: &Path) -> Result<String> {
    fs::read_to_string(path).map_err(|e| Error(format!("{}: {e}", path.display())))
}

fn collect_markdown(dir: &Path, out: &mut Vec<PathBuf>) -> Result {
    let entries = fs::read_dir(dir).map_err(|e| Error(format!("{}: {e}", dir.display())))?;
    for entry in entries.flatten() {
        let path = entry.path();
        if path.is_dir() {
            collect_markdown(&path, out)?;
        } else if path.extension().is_some_and(|e| e == "md") {
            out.push(path);
        }
    }
    Ok(())
}

/// The link targets of a markdown text (links and images, not code).
fn links(text: &str) -> Vec<String> {
    Parser::new_ext(text, Options::all())
        .filter_map(|ev| match ev {
            Event::Start(Tag::Link { dest_url, .. } | Tag::Image { dest_url, .. }) => {
                Some(dest_url.to_string())
            }
            _ => None,
        })
        .collect()
}

/// The anchors of a markdown text's headings, as mdBook and GitHub make
/// them: lower case, spaces to `-`, other punctuation but `-` and `_`
/// dropped; a repeated heading gets `-1`, `-2`, ...
fn anchors(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut heading: Option<String> = None;
    for ev in Parser::new_ext(text, Options::all()) {
        match ev {
            Event::Start(Tag::Heading { level, id, .. }) => {
                if let Some(id) = id {
                    out.insert(id.to_string());
                }
                heading = (level <= HeadingLevel::H6).then(String::new);
            }
            Event::Text(t) | Event::Code(t) => {
                if let Some(h) = heading.as_mut() {
                    h.push_str(&t);
                }
            }
            Event::End(TagEnd::Heading(_)) => {
                if let Some(h) = heading.take() {
                    let base = slug(&h);
                    let mut id = base.clone();
                    let mut n = 1;
                    while out.contains(&id) {
                        id = format!("{base}-{n}");
                        n += 1;
                    }
                    out.insert(id);
                }
            }
            _ => {}
        }
    }
    out
}

fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            c if c.is_alphanumeric() || c == '-' || c == '_' => Some(c),
            _ => None,
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn anchors_follow_mdbook() {
        let a = anchors("# 14. The drive's life\n## Faults\n## Faults\n### `cargo xtask` and CI\n");
        for want in [
            "14-the-drives-life",
            "faults",
            "faults-1",
            "cargo-xtask-and-ci",
        ] {
            assert!(a.contains(want), "{want} not in {a:?}");
        }
    }

    #[test]
    fn links_skip_code() {
        let l = links("see [a](a.md#x) and `[b](b.md)`\n\n    [c](c.md)\n![i](p.svg)");
        assert_eq!(l, vec!["a.md#x".to_string(), "p.svg".to_string()]);
    }
}
