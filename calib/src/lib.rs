//! Kinematic parameter calibration of a car-like vehicle (filled by the calib issue).
