"""helicalib.calibration"""
