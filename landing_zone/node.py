def main():
    print('node')
