//! Publishing frames on a v4l2loopback device.
