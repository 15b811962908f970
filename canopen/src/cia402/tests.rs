//! Unit tests of the profile.
