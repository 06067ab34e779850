# Run after lcm-gen (cmake -DDIR=<folder of generated .hpp> -P harden_decoders.cmake).
#
# lcm-gen's C++ decoders size each variable-length array from the count in the message before
# checking that the bytes are there: a 250-byte message that claims a 2 GB `data` array makes
# the receiver allocate and zero 2 GB (seconds of CPU, and enough such messages exhaust the
# robot PC's memory), and a string whose length field is 0 throws std::length_error. Every
# array element takes at least one byte on the wire, so a count larger than the bytes left is
# a corrupt message: this inserts that check before every resize and refuses non-positive
# string lengths, so such messages simply fail to decode (-1), as truncated ones do.
# Found by test/fuzz/bus_messages_fuzz.cc. The build fails if lcm-gen's output no longer has
# the shape these patterns expect.
file(GLOB headers "${DIR}/*.hpp")
if(NOT headers)
  message(FATAL_ERROR "harden_decoders: no generated headers in ${DIR}")
endif()
foreach(h ${headers})
  file(READ "${h}" text)
  if(text MATCHES "omni-hardened")
    continue()  # already done (the command reruns only with lcm-gen, but be safe)
  endif()
  string(REGEX MATCHALL "\\.resize\\(" all_resizes "${text}")
  string(REGEX REPLACE
    "\n( *)this->([A-Za-z0-9_]+)\\.resize\\(this->([A-Za-z0-9_]+)\\);"
    "\n\\1if (this->\\3 < 0 || this->\\3 > maxlen - pos) return -1;  // omni-hardened\n\\1this->\\2.resize(this->\\3);"
    text "${text}")
  string(REGEX MATCHALL "omni-hardened" checked "${text}")
  list(LENGTH all_resizes n_resize)
  list(LENGTH checked n_checked)
  if(NOT n_resize EQUAL n_checked)
    message(FATAL_ERROR "harden_decoders: ${h}: ${n_resize} resize calls but ${n_checked} "
                        "matched the expected 'this->A.resize(this->N);' form (lcm-gen changed?)")
  endif()
  string(REPLACE "if(__elem_len > maxlen - pos) return -1;"
                 "if(__elem_len <= 0 || __elem_len > maxlen - pos) return -1;  // omni-hardened"
                 text "${text}")
  # The top-level string fields (frame, source, ...): the same length check.
  string(REGEX REPLACE "if\\(__([A-Za-z0-9_]+)_len__ > maxlen - pos\\) return -1;"
         "if(__\\1_len__ <= 0 || __\\1_len__ > maxlen - pos) return -1;  // omni-hardened"
         text "${text}")
  file(WRITE "${h}" "${text}")
endforeach()
