"""helicalib.sim"""
