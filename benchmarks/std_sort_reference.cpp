// The orders libstdc++'s std::sort leaves equal keys in, for tests/mapping/test_stdsort.py.
// Input (stdin): cases, each "n depth k_0 ... k_{n-1}" (depth < 0: std::sort itself; else its
// introsort loop with that depth limit, then its final insertion sort). Output: one line per
// case, the original index of each element after sorting.
// Build: g++ -O2 -std=c++11 -o std_sort_reference std_sort_reference.cpp
#include <algorithm>
#include <cstdio>
#include <utility>
#include <vector>

struct Item {
    long key;
    long index;
    bool operator<(const Item& other) const { return key < other.key; }
};

int main() {
    long n, depth;
    while (std::scanf("%ld %ld", &n, &depth) == 2) {
        std::vector<Item> items(n);
        for (long i = 0; i < n; ++i) {
            std::scanf("%ld", &items[i].key);
            items[i].index = i;
        }
        if (depth < 0) {
            std::sort(items.begin(), items.end());
        } else if (n > 1) {
            std::__introsort_loop(items.begin(), items.end(), depth,
                                  __gnu_cxx::__ops::__iter_less_iter());
            std::__final_insertion_sort(items.begin(), items.end(),
                                        __gnu_cxx::__ops::__iter_less_iter());
        }
        for (long i = 0; i < n; ++i) std::printf(i ? " %ld" : "%ld", items[i].index);
        std::printf("\n");
    }
    return 0;
}
