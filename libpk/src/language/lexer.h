// Tokens of a model file (not installed).
#ifndef PK_SRC_LANGUAGE_LEXER_H_
#define PK_SRC_LANGUAGE_LEXER_H_

#include <string>
#include <vector>

namespace pk {
namespace internal {
namespace lang {

struct Token {
  enum class Kind { kIdentifier, kNumber, kPunct, kBlock, kText, kNewline, kEnd };
  Kind kind = Kind::kEnd;
  std::string text;    // as written (a block heading without '$', upper case; kText: the rest of a line)
  double number = 0;   // kNumber
  int line = 0, column = 0;
  size_t offset = 0, length = 0;  // in the source text
};

/// Splits model text into tokens. Comments (from '#' or ';' to the end of the line) are dropped;
/// newlines inside parentheses are too, so an expression may continue there. After $PROBLEM the
/// rest of the line is one kText token. Throws pk::InputError on a character that starts no token,
/// a malformed number or a NUL byte.
std::vector<Token> Tokenize(const std::string& text, const std::string& source);

}  // namespace lang
}  // namespace internal
}  // namespace pk

#endif  // PK_SRC_LANGUAGE_LEXER_H_
