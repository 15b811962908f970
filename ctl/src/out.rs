//! Where the commands' text goes: stdout and stderr, or a buffer while
//! the dashboard's console runs a command on its thread ([`capture`]).

use std::cell::RefCell;

thread_local! {
    static SINK: RefCell<Option<String>> = const { RefCell::new(None) };
}

/// Write `s` to the capture buffer if one is open on this thread, else to
/// stderr (`err`) or stdout.
pub(super) fn emit(s: &str, err: bool) {
    SINK.with(|k| match k.borrow_mut().as_mut() {
        Some(b) => b.push_str(s),
        None if err => eprint!("{s}"),
        None => print!("{s}"),
    })
}

/// Run `f` with everything it says collected: its result and the text.
pub(super) fn capture<R>(f: impl FnOnce() -> R) -> (R, String) {
    SINK.with(|k| *k.borrow_mut() = Some(String::new()));
    let r = f();
    let text = SINK.with(|k| k.borrow_mut().take()).unwrap_or_default();
    (r, text)
}

/// `println!` through [`emit`].
macro_rules! say {
    () => { $crate::out::emit("\n", false) };
    ($($t:tt)*) => { $crate::out::emit(&format!("{}\n", format_args!($($t)*)), false) };
}

/// `eprintln!` through [`emit`].
macro_rules! say_err {
    () => { $crate::out::emit("\n", true) };
    ($($t:tt)*) => { $crate::out::emit(&format!("{}\n", format_args!($($t)*)), true) };
}

/// `print!` through [`emit`].
macro_rules! say_raw {
    ($($t:tt)*) => { $crate::out::emit(&format!($($t)*), false) };
}
