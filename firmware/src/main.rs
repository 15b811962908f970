//! PLACEHOLDER firmware (filled by the firmware work).
#![no_std]
#![no_main]
