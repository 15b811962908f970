//! `cargo fuzz run device_commands` (or `cargo xtask fuzz --target device_commands`): the check
//! is [`foc_protocol_fuzz::device_commands`], also replayed on stable by
//! `cargo xtask fuzz --replay`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| foc_protocol_fuzz::device_commands(data));
