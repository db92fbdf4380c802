"""Model checks: does the model describe the data, or does the sensor show a term it leaves out?"""
