"""helicalib.report"""
