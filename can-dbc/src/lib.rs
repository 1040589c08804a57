//! DBC loading and a compiled CAN signal codec (filled by the DBC issue).
