"""helicalib.flux"""
