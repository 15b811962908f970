//! `cargo fuzz run frame_decoder` (or `cargo xtask fuzz --target frame_decoder`): the check
//! is [`foc_protocol_fuzz::frame_decoder`], also replayed on stable by
//! `cargo xtask fuzz --replay`.
#![no_main]

use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| foc_protocol_fuzz::frame_decoder(data));
