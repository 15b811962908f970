//! `cargo fuzz run message_decode` (or `cargo xtask fuzz --target message_decode`): the check
//! is [`foc_protocol_fuzz::message_decode`], also replayed on stable by
//! `cargo xtask fuzz --replay`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| foc_protocol_fuzz::message_decode(data));
