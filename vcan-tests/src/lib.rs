//! End-to-end tests on real vcan interfaces (filled by the vcan-tests issue).
