"""helicalib.geometry"""
