//! Test bench (PLACEHOLDER, filled by the test-bench work).
#![cfg_attr(not(feature = "std"), no_std)]
