"""warpface: muscle-driven facial expressions with wrinkles, on Warp."""
