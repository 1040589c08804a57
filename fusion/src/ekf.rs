//! The extended Kalman filter fusing rear and front odometry (filled next).
