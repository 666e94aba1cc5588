"""helicalib.devices"""
