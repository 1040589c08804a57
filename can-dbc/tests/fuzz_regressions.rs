//! Inputs found by the fuzz targets in can-dbc/fuzz/ (filled as findings arrive).
