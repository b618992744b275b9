"""The shipped IMU suit layouts (JSON files; live.imu.layout reads them, live.core.assets finds them)."""
