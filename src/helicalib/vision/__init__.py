"""helicalib.vision"""
