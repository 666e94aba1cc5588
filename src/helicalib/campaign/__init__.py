"""helicalib.campaign"""
