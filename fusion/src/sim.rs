//! The ground-truth vehicle simulator (filled next).
