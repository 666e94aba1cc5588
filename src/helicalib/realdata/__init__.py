"""helicalib.realdata"""
