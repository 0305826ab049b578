local ns = require "needlesim"
os.execute("echo escaped")
