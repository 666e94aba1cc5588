"""helicalib.store"""
