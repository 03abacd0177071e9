"""A non-linear multibody model of a Y25 wagon producing healthy and faulty bogie accelerations."""
