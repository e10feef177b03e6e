//! Seeded scenario generators.
