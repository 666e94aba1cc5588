"""helicalib.trough"""
